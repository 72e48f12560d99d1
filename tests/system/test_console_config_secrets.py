"""The configuration's secrets through the console's editor, against a real gateway over real
HTTP: the versions kept in the store never hold a secret in clear (read straight from the SQLite
file, as anyone with a copy of it could), a rollback still brings the secrets back exactly, and a
mask that stands for no secret of the file is refused at its key instead of becoming the
password."""

from __future__ import annotations

import asyncio
import contextlib
import os
import sqlite3
import stat
from pathlib import Path
from typing import Any

import yaml

from gateway.instruments.simulator import SimulatedLine
from tests.support import free_port
from tests.support.processes import gateway_process
from tests.system.test_console_config_edit import ADMIN_PASSWORD, browser_like, config

MQTT_PASSWORD = "plant-pass-4242"


def with_secrets(line: SimulatedLine, port: int, store: Path) -> dict[str, Any]:
    written = config(line, port)
    # A broker that isn't there: the bridge retries in the background, the password is kept.
    written["mqtt"] = {
        "host": "127.0.0.1",
        "port": free_port(),
        "username": "gateway",
        "password": MQTT_PASSWORD,
        "reconnect_max_s": 1,
    }
    written["storage"] = {"path": str(store)}
    return written


def kept_texts(store: Path) -> list[str]:
    with contextlib.closing(sqlite3.connect(f"file:{store}?mode=ro", uri=True)) as db:
        return [row[0] for row in db.execute("select text from config_versions order by id")]


async def test_versions_keep_no_secret_in_clear_and_a_rollback_brings_them_back(
    line: SimulatedLine, tmp_path: Path
) -> None:
    port, store = free_port(), tmp_path / "events.db"
    written = with_secrets(line, port, store)
    with gateway_process(written, tmp_path) as gateway:
        await asyncio.to_thread(gateway.wait_ready)
        original = gateway.config_file.read_text(encoding="utf-8")
        async with browser_like(port) as admin:
            assert (await admin.login("ada", ADMIN_PASSWORD)).status == 200
            shown = await admin.get_json("/api/config/file")
            longer = shown["text"].replace("timeout_ms: 100", "timeout_ms: 150")
            status, applied = await admin.post(
                "/api/config/apply", {"text": longer, "base": shown["base"]}
            )
            assert status == 200, applied
            on_disk = yaml.safe_load(gateway.config_file.read_text(encoding="utf-8"))
            assert on_disk["mqtt"]["password"] == MQTT_PASSWORD  # the file keeps it

            texts = kept_texts(store)
            assert len(texts) == 2  # the file as found, and the edit
            for text in texts:
                assert MQTT_PASSWORD not in text
                assert "scrypt$" not in text  # nor the users' password hashes
                assert "sealed:v1:" in text
            key_file = await asyncio.to_thread(os.stat, f"{store}.secrets-key")
            assert stat.S_IMODE(key_file.st_mode) == 0o600  # the box's key, its owner's alone

            shown_version = await admin.get_json("/api/config/versions/2")
            assert "sealed:" not in shown_version["text"]  # masked as any secret
            assert '"***' in shown_version["text"]

            status, rolled = await admin.post("/api/config/versions/1/rollback", {})
            assert status == 200, rolled
            assert gateway.config_file.read_text(encoding="utf-8") == original
            assert all(MQTT_PASSWORD not in text for text in kept_texts(store))


async def test_a_mask_that_stands_for_no_secret_is_refused_at_its_key(
    line: SimulatedLine, tmp_path: Path
) -> None:
    port, store = free_port(), tmp_path / "events.db"
    with gateway_process(with_secrets(line, port, store), tmp_path) as gateway:
        await asyncio.to_thread(gateway.wait_ready)
        original = gateway.config_file.read_text(encoding="utf-8")
        async with browser_like(port) as admin:
            assert (await admin.login("ada", ADMIN_PASSWORD)).status == 200
            shown = await admin.get_json("/api/config/file")
            # The password is the file's 5th secret (the 4 users' hashes come first).
            assert yaml.safe_load(shown["text"])["mqtt"]["password"] == "***5"
            for typed in ('"***99"', '"***"', "'***0'"):
                text = shown["text"].replace('password: "***5"', f"password: {typed}")
                body = {"text": text, "base": shown["base"]}
                status, checked = await admin.post("/api/config/check", body)
                assert status == 200
                assert checked["ok"] is False
                (problem,) = checked["problems"]
                assert problem["key"] == "password"
                assert "stands for no secret of the file" in problem["reason"]
                status, refused = await admin.post("/api/config/apply", body)
                assert status == 400, refused
                assert refused["problems"] == checked["problems"]
                assert gateway.config_file.read_text(encoding="utf-8") == original
            assert kept_texts(store) == []
