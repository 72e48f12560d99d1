"""Editing the configuration from the console, against a real `invt-gateway run --config FILE` on
the simulated line, over real HTTP: an admin checks a text as `check-config` does (each problem
at its key), applies one (kept as a version, written to the file, reloaded live), sees the
versions' diffs and rolls back; an operator is refused; every change is an audit event."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import aiohttp
import yaml

from gateway.instruments.simulator import SimulatedLine
from gateway.passwords import hash_password
from tests.support import free_port
from tests.support.console_support import (
    OPERATOR_PASSWORD,
    USERS,
    ConsoleClient,
)
from tests.support.processes import gateway_process

ADMIN_PASSWORD = "admin-secret-333"


def config(line: SimulatedLine, console_port: int) -> dict[str, Any]:
    admin = {"name": "ada", "password_hash": hash_password(ADMIN_PASSWORD), "role": "admin"}
    return {
        "gateway_id": "edited",
        "modbus_tcp": {"host": "127.0.0.1", "port": free_port()},
        "buses": [
            {"name": "line1", "port": line.path, "baudrate": 115200, "timeout_ms": 100},
        ],
        "drives": [
            {"name": "pump1", "bus": "line1", "address": 1},
            {"name": "fan2", "bus": "line1", "address": 2, "model": "gd20"},
        ],
        "console": {
            "enabled": True,
            "host": "127.0.0.1",
            "port": console_port,
            "users": [*USERS, admin],
        },
    }


@contextlib.asynccontextmanager
async def browser_like(port: int) -> AsyncIterator[ConsoleClient]:
    """A client with its own cookie jar, as `console_client` gives for an in-process gateway."""
    async with aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True)) as session:
        yield ConsoleClient(session, f"http://127.0.0.1:{port}")


async def test_an_admin_edits_checks_applies_and_rolls_back_an_operator_cannot(
    line: SimulatedLine, tmp_path: Path
) -> None:
    port = free_port()
    written = config(line, port)
    with gateway_process(written, tmp_path) as gateway:
        await asyncio.to_thread(gateway.wait_ready)
        original = gateway.config_file.read_text(encoding="utf-8")
        async with browser_like(port) as operator, browser_like(port) as admin:
            assert (await operator.login("olga", OPERATOR_PASSWORD)).status == 200
            async with operator.session.get(f"{operator.base}/api/config/file") as response:
                assert response.status == 403
                assert "admins only" in (await response.json())["error"]
            status, refused = await operator.post("/api/config/apply", {"text": original})
            assert status == 403
            assert "olga (operator) may not see or change the configuration" in refused["error"]

            assert (await admin.login("ada", ADMIN_PASSWORD)).status == 200
            shown = await admin.get_json("/api/config/file")
            assert shown["path"] == str(gateway.config_file)
            assert "scrypt$" not in shown["text"]  # no password hash leaves the gateway
            base = shown["base"]
            assert 'password_hash: "***1"' in shown["text"]

            # A mistake: checked as check-config checks a file, the key and the reason given.
            wrong = shown["text"].replace("address: 2", "address: 300")
            status, checked = await admin.post("/api/config/check", {"text": wrong, "base": base})
            assert status == 200
            assert checked["ok"] is False
            (problem,) = checked["problems"]
            assert problem["key"] == "drives[1] (fan2).address"
            assert "247" in problem["reason"]
            at = wrong.splitlines()[problem["line"] - 1]  # the line the problem names
            assert "address: 300" in at
            status, refused = await admin.post("/api/config/apply", {"text": wrong, "base": base})
            assert status == 400
            assert refused["problems"] == checked["problems"]
            assert gateway.config_file.read_text(encoding="utf-8") == original

            # What would change, and what would wait for a restart, before applying.
            moved = shown["text"].replace(f"port: {port}", f"port: {free_port()}")
            status, checked = await admin.post("/api/config/check", {"text": moved, "base": base})
            assert checked["ok"] is True
            assert checked["restart_needed"] == ["console.port"]

            longer = shown["text"].replace("timeout_ms: 100", "timeout_ms: 150")
            status, applied = await admin.post(
                "/api/config/apply", {"text": longer, "note": "longer cable", "base": base}
            )
            assert status == 200, applied
            assert applied["version"] == 2  # 1: the file as it was found
            assert applied["changed"] == ["buses reopened: line1"]
            assert applied["outcome"][0].startswith("applied:")
            on_disk = yaml.safe_load(gateway.config_file.read_text(encoding="utf-8"))
            assert on_disk["buses"][0]["timeout_ms"] == 150
            # The secrets shown as *** are the file's own again.
            assert on_disk["console"]["users"] == written["console"]["users"]
            running = (await admin.get_json("/api/config"))["configuration"]
            assert running["buses"][0]["timeout_ms"] == 150

            versions = (await admin.get_json("/api/config/versions"))["versions"]
            assert [(v["id"], v["user"]) for v in versions] == [(2, "ada"), (1, "(file)")]
            assert versions[0]["note"] == "longer cable"
            assert "-  timeout_ms: 100\n+  timeout_ms: 150\n" in versions[0]["diff"]
            assert "scrypt$" not in versions[1]["diff"]

            # The text loaded before the apply is stale now: refused, nothing changed.
            status, stale = await admin.post("/api/config/apply", {"text": longer, "base": base})
            assert status == 409
            assert "changed since this text was loaded" in stale["error"]

            status, rolled = await admin.post("/api/config/versions/1/rollback", {})
            assert status == 200, rolled
            assert rolled["version"] == 3
            assert gateway.config_file.read_text(encoding="utf-8") == original
            running = (await admin.get_json("/api/config"))["configuration"]
            assert running["buses"][0]["timeout_ms"] == 100

            events = (await admin.get_json("/api/events?kind=config_changed"))["events"]
        texts = [(e["user"], e["text"], e["result"]) for e in reversed(events)]
        assert texts[0][0] == "olga"
        assert texts[0][2].startswith("refused: olga (operator)")
        assert texts[1][0] == "ada"
        assert texts[1][2].startswith("refused: the configuration")
        assert texts[2] == (
            "ada",
            "configuration version 2 applied (longer cable): buses reopened: line1",
            "ok",
        )
        assert texts[3][0] == "ada"
        assert "changed since this text was loaded" in texts[3][2]
        assert texts[4] == (
            "ada",
            "configuration rolled back to version 1 (now version 3): buses reopened: line1",
            "ok",
        )
        assert all(e["category"] == "configuration" for e in events)
        assert len(texts) == 5
        assert gateway.log.count("config reloaded") == 2
