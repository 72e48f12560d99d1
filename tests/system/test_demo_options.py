"""`invt-gateway demo`'s options as a newcomer types them: a wrong value is refused naming the
option typed (not only the configuration key behind it), and a port taken at start names the
option that changes it. Real `invt-gateway` subprocesses; a configuration without MQTT, so no
broker is involved."""

from __future__ import annotations

import socket
from importlib import resources
from pathlib import Path

import pytest
import yaml

from gateway.exit_codes import EXIT_STARTUP, EXIT_USAGE
from tests.support.processes import run_cli


@pytest.fixture
def demo_without_mqtt(tmp_path: Path) -> str:
    text = resources.files("gateway").joinpath("data/demo.yaml").read_text(encoding="utf-8")
    config = yaml.safe_load(text)
    del config["mqtt"]
    path = tmp_path / "demo.yaml"
    path.write_text(yaml.safe_dump(config), encoding="utf-8")
    return str(path)


@pytest.mark.parametrize(
    ("option", "value", "reason"),
    [
        ("--port", "70000", "less than or equal to 65535 (modbus_tcp.port)"),
        ("--console-port", "-5", "greater than or equal to 0 (console.port)"),
        ("--mqtt-port", "1884", "this configuration has no mqtt section"),
    ],
)
def test_a_wrong_option_value_is_refused_naming_the_option(
    demo_without_mqtt: str, option: str, value: str, reason: str
) -> None:
    result = run_cli("demo", "-c", demo_without_mqtt, "--console-port", "0", option, value)
    assert result.returncode == EXIT_USAGE, result.stderr
    assert f"invt-gateway demo: {option} {value}: " in result.stderr
    assert reason in result.stderr


def test_a_taken_port_names_the_option_that_changes_it(demo_without_mqtt: str) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        result = run_cli(
            "demo", "-c", demo_without_mqtt, "--console-port", "0", "--port", str(port)
        )
    assert result.returncode == EXIT_STARTUP, result.stderr
    assert f"port {port} is already in use" in result.stderr
    assert "change modbus_tcp.host/port (or the option --port)" in result.stderr


def test_a_negative_burst_period_is_a_usage_error_not_a_traceback(demo_without_mqtt: str) -> None:
    result = run_cli("demo", "-c", demo_without_mqtt, "--console-port", "0", "--burst-ms", "-5")
    assert result.returncode == EXIT_USAGE
    assert "argument --burst-ms: -5: must be 0 or more" in result.stderr
    assert "Traceback" not in result.stderr
