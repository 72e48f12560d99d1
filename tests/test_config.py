"""Configuration files as a user writes them, checked by the real `invt-gateway` command."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

GOOD = """
modbus_tcp: {host: 0.0.0.0, port: 5020, max_connections: 32, idle_timeout_s: 300}
buses:
  - name: line1
    port: /dev/serial/by-id/usb-FTDI-line1
    baudrate: 19200
    parity: E
    stopbits: 1
    timeout_ms: 300
    retries: 2
drives:
  - {name: pump1, bus: line1, address: 1}
  - {name: fan3,  bus: line1, address: 3, unit_id: 13, model: gd350, timeout_ms: 150}
"""


def check_config(tmp_path: Path, text: str) -> subprocess.CompletedProcess[str]:
    path = tmp_path / "config.yaml"
    path.write_text(text)
    return subprocess.run(
        [sys.executable, "-m", "gateway", "check-config", "--config", str(path)],
        capture_output=True,
        text=True,
        timeout=60,
    )


def test_the_issue_example_is_valid_and_prints_the_routing_table(tmp_path: Path) -> None:
    result = check_config(tmp_path, GOOD)
    assert result.returncode == 0, result.stderr
    rows = [line.split() for line in result.stdout.splitlines()[2:]]
    # unit id, drive, bus, address, model ...: the unit id defaults to the address.
    assert rows[0][:5] == ["1", "pump1", "line1", "1", "gd20"]
    assert rows[1][:5] == ["13", "fan3", "line1", "3", "gd350"]
    assert "150 ms" in result.stdout


@pytest.mark.parametrize(
    ("change", "key_path", "reason"),
    [
        (("retries: 2", "retries: 2\n    retrys: 3"), "buses[0] (line1).retrys", "unknown key"),
        (("unit_id: 13", "unit_id: 1"), "drives[1] (fan3).unit_id", "duplicate unit_id 1"),
        (
            ("bus: line1, address: 3", "bus: line2, address: 3"),
            "drives[1] (fan3).bus",
            "bus 'line2' is not defined",
        ),
        (("address: 3", "address: 248"), "drives[1] (fan3).address", "less than or equal to 247"),
        (("baudrate: 19200", "baudrate: 19000"), "buses[0] (line1).baudrate", "must be one of"),
        (("parity: E", "parity: X"), "buses[0] (line1).parity", "'N', 'E' or 'O'"),
        (("model: gd350", "model: gd999"), "drives[1] (fan3).model", "gd999"),
        (("port: 5020", "port: 70000"), "modbus_tcp.port", "less than or equal to 65535"),
        (
            ("retries: 2", "retries: 2\n    rs485: {mode: auto}"),
            "buses[0] (line1).rs485.mode",
            "'kernel' or 'rts'",
        ),
        (
            ("retries: 2", "retries: 2\n    rs485: {mode: rts, delay_after_tx_ms: -1}"),
            "buses[0] (line1).rs485.delay_after_tx_ms",
            "greater than or equal to 0",
        ),
    ],
)
def test_a_bad_file_names_the_key_and_the_reason(
    tmp_path: Path, change: tuple[str, str], key_path: str, reason: str
) -> None:
    result = check_config(tmp_path, GOOD.replace(*change))
    assert result.returncode == 3
    assert key_path in result.stderr
    assert reason in result.stderr
    assert "Traceback" not in result.stderr


def test_rs485_direction_control_is_accepted(tmp_path: Path) -> None:
    text = GOOD.replace(
        "retries: 2",
        "retries: 2\n    rs485: {mode: kernel, rts_level_for_tx: low, delay_before_tx_ms: 1}",
    )
    result = check_config(tmp_path, text)
    assert result.returncode == 0, result.stderr


def test_two_buses_on_one_port_are_refused(tmp_path: Path) -> None:
    text = GOOD.replace(
        "drives:",
        "  - {name: line2, port: /dev/serial/by-id/usb-FTDI-line1}\ndrives:",
    )
    result = check_config(tmp_path, text)
    assert result.returncode == 3
    assert "buses[1] (line2).port: duplicate port /dev/serial/by-id/usb-FTDI-line1" in result.stderr


def test_missing_file_and_broken_yaml(tmp_path: Path) -> None:
    result = subprocess.run(
        [sys.executable, "-m", "gateway", "check-config", "--config", str(tmp_path / "nope.yaml")],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 3
    assert "cannot read the file" in result.stderr
    result = check_config(tmp_path, "buses: [name: x")
    assert result.returncode == 3
    assert "not valid YAML" in result.stderr


def test_missing_required_keys(tmp_path: Path) -> None:
    result = check_config(tmp_path, "drives: []\n")
    assert result.returncode == 3
    assert "buses: required key is missing" in result.stderr
