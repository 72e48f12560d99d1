"""Configuration files as a user writes them, checked by the real `invt-gateway` command."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from tests.support.processes import check_config

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


def test_every_problem_of_a_file_in_one_run_cross_field_ones_included(tmp_path: Path) -> None:
    # Four mistakes, as a newcomer makes them: a typo in a key, a value out of range, a drive on
    # a bus that doesn't exist and a duplicate unit id. The last two are cross-field checks,
    # which pydantic runs only once every field is valid.
    text = (
        GOOD.replace("retries: 2", "retrys: 2")
        .replace("address: 3", "address: 248")
        .replace("unit_id: 13", "unit_id: 1")
        + "  - {name: pump2, bus: line9, address: 2}\n"
    )
    result = check_config(tmp_path, text)
    assert result.returncode == 3
    problems = result.stderr.splitlines()[1:]
    assert problems == [
        "  line 10: buses[0] (line1).retrys: unknown key; did you mean retries?",
        "  line 13: drives[1] (fan3).address: Input should be less than or equal to 247",
        "  line 13: drives[1] (fan3).unit_id: duplicate unit_id 1 (also drives[0] (pump1))",
        "  line 14: drives[2] (pump2).bus: bus 'line9' is not defined (buses: line1)",
    ]


def test_a_typo_names_the_nearest_key_or_model_and_every_mistake_its_line(tmp_path: Path) -> None:
    """As a newcomer types them: `baudrat`, `modle`, `gd35O` (a letter O), an unknown section;
    each answered with what was meant and where in the file it is."""
    text = """buses:
  - name: line1
    port: /dev/ttyUSB0
    baudrat: 9600
drives:
  - name: pump1
    bus: line1
    address: 1
    modle: gd350
  - name: fan2
    bus: line1
    address: 2
    model: gd35O
mqt: {host: broker}
"""
    result = check_config(tmp_path, text)
    assert result.returncode == 3
    problems = result.stderr.splitlines()[1:]
    assert problems[:2] == [
        "  line 4: buses[0] (line1).baudrat: unknown key; did you mean baudrate?",
        "  line 9: drives[0] (pump1).modle: unknown key; did you mean model?",
    ]
    assert problems[2].startswith(
        "  line 13: drives[1] (fan2).model: unknown drive profile 'gd35O' (did you mean gd350?)"
    )
    assert problems[3] == "  line 14: mqt: unknown key; did you mean mqtt?"
    assert len(problems) == 4
    # Nothing near: no guess.
    result = check_config(tmp_path, text.replace("baudrat", "speed"))
    assert "line 4: buses[0] (line1).speed: unknown key\n" in result.stderr


def test_a_cross_field_problem_that_follows_from_a_reported_one_is_left_out(
    tmp_path: Path,
) -> None:
    # Without `buses`, no drive's bus can be defined: that is one problem, not one per drive.
    result = check_config(
        tmp_path, GOOD.split("buses:")[0] + "drives: [{name: a, bus: x, address: 1}]\n"
    )
    assert result.returncode == 3
    assert result.stderr.splitlines()[1:] == ["  buses: required key is missing"]


def test_a_yaml_syntax_error_names_the_file_line_and_column(tmp_path: Path) -> None:
    # The third line is indented one space less than its sibling: a YAML syntax error.
    text = "buses:\n  - name: line1\n   port: /dev/ttyUSB0\n"
    result = check_config(tmp_path, text)
    assert result.returncode == 3
    first, reason = result.stderr.splitlines()
    assert first == f"invt-gateway: {tmp_path / 'config.yaml'}: invalid configuration"
    assert reason.startswith("  line 3, column 4: not valid YAML: ")
    assert "<unicode string>" not in result.stderr


def test_version_1_is_read_and_an_unknown_version_is_refused_naming_the_ones_read(
    tmp_path: Path,
) -> None:
    assert check_config(tmp_path, "version: 1\n" + GOOD).returncode == 0
    result = check_config(tmp_path, "version: 2\n" + GOOD)
    assert result.returncode == 3
    assert result.stderr.splitlines()[1:] == [
        "  version: 2 is not a version this gateway reads (it reads 1)"
    ]


@pytest.mark.parametrize(
    ("key", "value", "reason"),
    [
        ("base_topic", "site.a", "no '.' in a topic"),
        ("base_topic", "plant/+/x", "no '+' in a topic"),
        ("base_topic", "plant/#", "no '#' in a topic"),
        ("base_topic", "plant//a", "no empty level"),
        ("discovery_prefix", "home.assistant", "no '.' in a topic"),
        ("discovery_prefix", "ha/", "no empty level"),
    ],
)
def test_mqtt_topics_that_would_not_travel_between_brokers_are_refused(
    tmp_path: Path, key: str, value: str, reason: str
) -> None:
    text = GOOD + f"mqtt: {{host: 127.0.0.1, {key}: '{value}'}}\n"
    result = check_config(tmp_path, text)
    assert result.returncode == 3
    assert f"mqtt.{key}" in result.stderr
    assert reason in result.stderr
