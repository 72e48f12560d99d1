"""What `invt-gateway run` loads is the service and nothing else: no simulator, bench, stress or
demo broker (`gateway.instruments`), no OPC UA stack unless `opcua:` asks for it (asyncua), shown
by Python's own import log (`-X importtime`) of a real `run` process serving a simulated line
until it is stopped."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import yaml

from gateway.instruments.simulator import SimulatedLine
from tests.support import free_port, read_state_word
from tests.support.processes import LineCollector


def test_run_imports_nothing_of_the_instruments(tmp_path: Path) -> None:
    port = free_port()
    with SimulatedLine(addresses=[1], baudrate=115200) as line:
        config = tmp_path / "config.yaml"
        config.write_text(
            yaml.safe_dump(
                {
                    "modbus_tcp": {"host": "127.0.0.1", "port": port},
                    "buses": [{"name": "line1", "port": line.path, "baudrate": 115200}],
                    "drives": [{"name": "pump1", "bus": "line1", "address": 1, "poll": []}],
                }
            )
        )
        process = subprocess.Popen(
            [sys.executable, "-X", "importtime", "-m", "gateway", "run", "--config", str(config)],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
            env={**os.environ, "STATE_DIRECTORY": str(tmp_path)},
        )
        assert process.stderr is not None
        log = LineCollector(process.stderr)
        try:
            log.wait_for("ready:")
            assert read_state_word(port, 1) == bytes.fromhex("03 02 00 03")  # it serves
            process.send_signal(signal.SIGTERM)
            assert process.wait(10) == 0
        finally:
            if process.poll() is None:
                process.kill()
                process.wait(5)
            log.join()
            process.stderr.close()
    imported = [
        line.split("|")[-1].strip() for line in log.lines if line.startswith("import time:")
    ]
    assert "gateway.app" in imported  # the log is what it seems
    instruments = [name for name in imported if name.startswith("gateway.instruments")]
    assert instruments == []
    others = [
        name for name in imported if name.split(".")[0] in ("pymodbus", "selenium", "asyncua")
    ]
    assert others == []
