"""A feature that dies of a bug stops the service: exit code 1 and a one-line reason, so that
systemd or Docker restart it (`Restart=on-failure`) rather than leave it running without, say,
its polls, or its console's charts frozen. A real process (the service's own `serve`), real
features, real bugs (`tests/peers/gateway_with_a_bug.py` says how they are made)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import yaml

from gateway.exit_codes import EXIT_FAILURE
from gateway.instruments.simulator import SimulatedLine
from tests.support import free_port

EXIT_WITHIN_S = 15.0


def run_with_a_bug(tmp_path: Path, bug: str, **sections: Any) -> subprocess.CompletedProcess[str]:
    """`invt-gateway run` with `bug` made once it is ready (`tests/peers/gateway_with_a_bug.py`)."""
    with SimulatedLine(addresses=[1], baudrate=115200) as line:
        config = {
            "gateway_id": "bug",
            "modbus_tcp": {"host": "127.0.0.1", "port": free_port()},
            "buses": [{"name": "line1", "port": line.path, "baudrate": 115200}],
            "drives": [
                {
                    "name": "pump1",
                    "bus": "line1",
                    "address": 1,
                    "poll": [{"name": "state", "start": 0x2100, "count": 3, "interval_ms": 100}],
                }
            ],
            **sections,
        }
        config_file = tmp_path / "gateway.yaml"
        config_file.write_text(yaml.safe_dump(config), encoding="utf-8")
        return subprocess.run(
            [sys.executable, "-m", "tests.peers.gateway_with_a_bug", str(config_file), bug],
            capture_output=True,
            text=True,
            timeout=EXIT_WITHIN_S,
            cwd=Path(__file__).parents[2],
            check=False,
        )


def the_reason(result: subprocess.CompletedProcess[str]) -> str:
    """The last line, which says why the service stopped; asserting it ran first and exited 1."""
    assert result.returncode == EXIT_FAILURE, result.stderr
    assert "ready:" in result.stderr  # it ran, then died: not a failed start
    last = result.stderr.strip().splitlines()[-1]
    assert "CRITICAL" in last
    return last


def test_a_feature_that_dies_of_a_bug_stops_the_service_with_exit_code_1(
    tmp_path: Path,
) -> None:
    result = run_with_a_bug(tmp_path, "poller")

    assert "stopping: poller died: ValueError(" in the_reason(result), result.stderr


def test_a_bug_in_the_consoles_sampler_stops_the_service_rather_than_freezing_its_charts(
    tmp_path: Path,
) -> None:
    console = {"enabled": True, "port": 0, "anonymous_view": True}

    result = run_with_a_bug(tmp_path, "console-sampler", console=console)

    reason = the_reason(result)
    assert "stopping: console:sampler died: KeyError('unannounced')" in reason, result.stderr
