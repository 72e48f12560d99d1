"""A configuration the gateway could not start on is refused wherever it is checked, each problem
at its key with the reason: by `check-config` (a real subprocess, exit code 3), by `run` itself
before it starts anything (a line a problem, exit code 4), by the console's
Check and Apply on a running gateway (real HTTP: Apply answers 400 and neither writes the file
nor keeps a version), and by a reload of the file edited by hand. The four cases are the ones
that passed all of them and then failed the next start: the Modbus-TCP port equal to the
console's, `modbus_tcp.tls` on with its certificate files missing, a console certificate file
that is not a certificate, the metrics port equal to the Modbus-TCP port."""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import yaml

from gateway.exit_codes import EXIT_CONFIG, EXIT_STARTUP
from gateway.instruments.simulator import SimulatedLine
from tests.support import free_port
from tests.support.processes import check_config, gateway_process, run_cli
from tests.system.test_console_config_edit import ADMIN_PASSWORD, browser_like, config

Edit = Callable[[dict[str, Any], Path], None]


def same_port_as_the_console(edited: dict[str, Any], _: Path) -> None:
    edited["modbus_tcp"]["port"] = edited["console"]["port"]


def tls_files_missing(edited: dict[str, Any], folder: Path) -> None:
    edited["modbus_tcp"]["tls"] = {
        "enabled": True,
        "port": 0,
        "cert_file": str(folder / "missing-cert.pem"),
        "key_file": str(folder / "missing-key.pem"),
        "ca_file": str(folder / "missing-ca.pem"),
    }


def console_cert_not_a_certificate(edited: dict[str, Any], folder: Path) -> None:
    notes = folder / "notes.txt"
    notes.write_text("not a certificate\n", encoding="utf-8")
    edited["console"]["cert_file"] = str(notes)
    edited["console"]["key_file"] = str(notes)


def metrics_on_the_modbus_port(edited: dict[str, Any], _: Path) -> None:
    edited["metrics"] = {"enabled": True, "host": "127.0.0.1", "port": edited["modbus_tcp"]["port"]}


CASES: list[tuple[Edit, str, str]] = [
    (same_port_as_the_console, "console.port", "is also modbus_tcp.port"),
    (tls_files_missing, "modbus_tcp.tls.cert_file", "No such file"),
    (console_cert_not_a_certificate, "console.cert_file", "not a PEM certificate"),
    (metrics_on_the_modbus_port, "metrics.port", "is also modbus_tcp.port"),
]
IDS = [case[0].__name__ for case in CASES]


@pytest.mark.parametrize(("edit", "key", "reason"), CASES, ids=IDS)
def test_check_config_refuses_what_could_not_start_naming_key_and_reason(
    line: SimulatedLine, tmp_path: Path, edit: Edit, key: str, reason: str
) -> None:
    edited = config(line, free_port())
    edit(edited, tmp_path)
    result = check_config(tmp_path, yaml.safe_dump(edited))
    assert result.returncode == EXIT_CONFIG, result.stdout + result.stderr
    said = [row for row in result.stderr.splitlines() if row.strip().startswith(f"{key}:")]
    assert said, result.stderr
    assert reason in said[0]
    assert "valid" not in result.stdout


@pytest.mark.parametrize(("edit", "key", "reason"), CASES, ids=IDS)
def test_run_refuses_it_before_starting_one_line_a_problem_exit_4(
    line: SimulatedLine, tmp_path: Path, edit: Edit, key: str, reason: str
) -> None:
    edited = config(line, free_port())
    edit(edited, tmp_path)
    path = tmp_path / "gateway.yaml"
    path.write_text(yaml.safe_dump(edited), encoding="utf-8")
    result = run_cli("run", "--config", str(path))
    assert result.returncode == EXIT_STARTUP, result.stderr
    said = [row for row in result.stderr.splitlines() if "cannot start" in row]
    assert said, result.stderr
    assert f"cannot start: {key}: " in said[0]  # the first problem in the file's order
    assert reason in said[0]
    assert "Traceback" not in result.stderr


async def test_the_consoles_check_and_apply_refuse_what_could_not_start(
    line: SimulatedLine, tmp_path: Path
) -> None:
    port = free_port()
    with gateway_process(config(line, port), tmp_path) as gateway:
        await asyncio.to_thread(gateway.wait_ready)
        original = gateway.config_file.read_text(encoding="utf-8")
        async with browser_like(port) as admin:
            assert (await admin.login("ada", ADMIN_PASSWORD)).status == 200
            shown = await admin.get_json("/api/config/file")
            for edit, key, reason in CASES:
                edited = yaml.safe_load(original)
                edit(edited, tmp_path)
                # The secrets as the page has them (masked), the rest as edited.
                edited["console"]["users"] = yaml.safe_load(shown["text"])["console"]["users"]
                text = yaml.safe_dump(edited)
                body = {"text": text, "base": shown["base"]}
                status, checked = await admin.post("/api/config/check", body)
                assert status == 200
                assert checked["ok"] is False, (edit.__name__, checked)
                problems = {p["key"]: p["reason"] for p in checked["problems"]}
                assert reason in problems.get(key, ""), (edit.__name__, problems)
                status, refused = await admin.post("/api/config/apply", body)
                assert status == 400, (edit.__name__, refused)
                assert refused["problems"] == checked["problems"]
                assert gateway.config_file.read_text(encoding="utf-8") == original
            versions = (await admin.get_json("/api/config/versions"))["versions"]
            assert versions == []  # nothing applied, nothing kept

        # The same file edited by hand and reloaded (`invt-gateway reload`, as systemctl
        # reload does): refused with the key, the running configuration kept.
        by_hand = yaml.safe_load(original)
        metrics_on_the_modbus_port(by_hand, tmp_path)
        gateway.config_file.write_text(yaml.safe_dump(by_hand), encoding="utf-8")
        refused_reload = await asyncio.to_thread(
            run_cli, "reload", "--config", str(gateway.config_file)
        )
        assert refused_reload.returncode == EXIT_CONFIG, refused_reload.stdout
        assert "metrics.port: " in refused_reload.stderr
        assert "is also modbus_tcp.port" in refused_reload.stderr
        assert gateway.process.poll() is None
