"""A port the gateway can't listen on: `run` and `demo` say so in one line and exit 4.

What a person sees when the Modbus-TCP port is taken (another gateway, a demo left running,
another program), when `modbus_tcp.host` is not an address of this machine, or when the metrics
port is taken: one line naming the address, the port and the likely cause, exit code 4 (the
README's "failure to start", distinct from 1, a failure while serving), and no traceback.
"""

from __future__ import annotations

import socket
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml

from gateway.exit_codes import EXIT_STARTUP
from gateway.instruments.commands.demo import demo_config_text
from gateway.instruments.simulator import SimulatedLine
from tests.support.processes import run_cli

pytestmark = pytest.mark.line(addresses=[1], baudrate=19200)


@pytest.fixture
def taken_port() -> Iterator[int]:
    """A port on 127.0.0.1 another program listens on."""
    with socket.socket() as other:
        other.bind(("127.0.0.1", 0))
        other.listen()
        yield other.getsockname()[1]


def write_config(directory: Path, line: SimulatedLine, **sections: Any) -> str:
    config = {
        "gateway_id": "startup",
        "buses": [{"name": "line1", "port": line.path}],
        "drives": [{"name": "pump1", "bus": "line1", "address": 1}],
        **sections,
    }
    path = directory / "gateway.yaml"
    path.write_text(yaml.safe_dump(config), encoding="utf-8")
    return str(path)


def the_one_error(stderr: str) -> str:
    """The error line; asserting there is exactly one and no traceback."""
    assert "Traceback" not in stderr, stderr
    errors = [line for line in stderr.splitlines() if "cannot start" in line]
    assert len(errors) == 1, stderr
    return errors[0]


def test_run_on_a_taken_port_says_so_in_one_line_and_exits_4(
    tmp_path: Path, line: SimulatedLine, taken_port: int
) -> None:
    config = write_config(tmp_path, line, modbus_tcp={"host": "127.0.0.1", "port": taken_port})

    result = run_cli("run", "--config", config)

    assert result.returncode == EXIT_STARTUP
    error = the_one_error(result.stderr)
    assert f"Modbus-TCP cannot listen on 127.0.0.1:{taken_port}" in error
    assert "already in use" in error
    assert "another invt-gateway" in error
    assert "modbus_tcp.host/port" in error


def test_run_on_an_address_not_of_this_machine_names_the_host_key(
    tmp_path: Path, line: SimulatedLine
) -> None:
    # 192.0.2.0/24 is TEST-NET-1 (RFC 5737): never an address of a real machine.
    config = write_config(tmp_path, line, modbus_tcp={"host": "192.0.2.7", "port": 5020})

    result = run_cli("run", "--config", config)

    assert result.returncode == EXIT_STARTUP
    error = the_one_error(result.stderr)
    assert "192.0.2.7:5020" in error
    assert "not an address of this machine" in error


def test_run_with_the_metrics_port_taken_names_the_metrics_keys(
    tmp_path: Path, line: SimulatedLine, taken_port: int
) -> None:
    config = write_config(
        tmp_path,
        line,
        modbus_tcp={"host": "127.0.0.1", "port": 0},
        metrics={"enabled": True, "host": "127.0.0.1", "port": taken_port},
    )

    result = run_cli("run", "--config", config)

    assert result.returncode == EXIT_STARTUP
    error = the_one_error(result.stderr)
    assert f"metrics and health cannot listen on 127.0.0.1:{taken_port}" in error
    assert "metrics.host/port" in error


def test_demo_on_a_taken_port_says_so_in_one_line_and_exits_4(
    tmp_path: Path, taken_port: int
) -> None:
    config = yaml.safe_load(demo_config_text(None))
    config["console"]["port"] = 0  # a free one: demos run side by side here
    del config["mqtt"]  # this test is about the Modbus-TCP port: no broker touched
    config_file = tmp_path / "demo.yaml"
    config_file.write_text(yaml.safe_dump(config), encoding="utf-8")

    result = run_cli("demo", "--config", str(config_file), "--port", str(taken_port))

    assert result.returncode == EXIT_STARTUP
    error = the_one_error(result.stderr)
    assert f"Modbus-TCP cannot listen on 127.0.0.1:{taken_port}" in error
    assert "already in use" in error
