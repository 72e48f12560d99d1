"""A feature that dies of a bug stops the service: exit code 1 and a one-line reason, so that
systemd or Docker restart it (`Restart=on-failure`) rather than leave it running without, say,
its polls. A real process (the service's own `serve`), a real poller, a real bug
(`tests/peers/gateway_with_a_bug.py` says how it is made)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import yaml

from gateway.instruments.simulator import SimulatedLine
from tests.support import free_port

EXIT_WITHIN_S = 15.0


def test_a_feature_that_dies_of_a_bug_stops_the_service_with_exit_code_1(
    tmp_path: Path,
) -> None:
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
        }
        config_file = tmp_path / "gateway.yaml"
        config_file.write_text(yaml.safe_dump(config), encoding="utf-8")
        result = subprocess.run(
            [sys.executable, "-m", "tests.peers.gateway_with_a_bug", str(config_file)],
            capture_output=True,
            text=True,
            timeout=EXIT_WITHIN_S,
            cwd=Path(__file__).parent.parent,
            check=False,
        )
    assert result.returncode == 1, result.stderr
    last = result.stderr.strip().splitlines()[-1]
    assert "CRITICAL" in last
    assert "stopping: poller died: ValueError(" in last, result.stderr
    assert "ready:" in result.stderr  # it ran, then died: not a failed start
