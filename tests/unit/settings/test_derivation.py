"""What the running parts get from a file: units converted (milliseconds to seconds), defaults
resolved (a drive's unit id and poll groups, the silence between frames, the MQTT client id, the
store's place), a feature left out as None, and the configuration shown with its secrets masked."""

from __future__ import annotations

from pathlib import Path

import pytest

from gateway.config import ENV_STATE_DIRECTORY, parse_config
from gateway.profile import get_profile
from gateway.settings import GatewaySettings, runtime_settings
from gateway.settings.shown import MASK

FILE = """
gateway_id: hall2
buses:
  - {name: line1, port: /dev/ttyUSB0, baudrate: 9600, parity: E, timeout_ms: 250,
     char_timeout_ms: 30, drain_ms: 40, turnaround_ms: 120}
  - {name: line2, port: /dev/ttyUSB1, baudrate: 19200, gap_ms: 5,
     rs485: {mode: rts, delay_before_tx_ms: 1, delay_after_tx_ms: 2}}
drives:
  - {name: pump1, bus: line1, address: 1}
  - name: fan3
    bus: line2
    address: 3
    unit_id: 13
    model: gd350
    timeout_ms: 150
    retries: 0
    poll: [{name: fast, start: 0x2100, count: 3, interval_ms: 250}]
"""


def settings(text: str = FILE) -> GatewaySettings:
    return runtime_settings(parse_config(text))


def test_a_buses_times_are_in_seconds_and_its_gap_is_three_and_a_half_characters() -> None:
    line1, line2 = settings().buses
    assert line1.timeout_s == pytest.approx(0.25)
    assert line1.line.char_timeout_s == pytest.approx(0.030)
    assert line1.line.drain_s == pytest.approx(0.040)
    assert line1.line.turnaround_s == pytest.approx(0.120)
    # 9600 8E1: 11 bits a character, t3.5 = 3.5 * 11 / 9600 s (Modbus over serial line, 2.5.1.1).
    assert line1.line.gap_s == pytest.approx(3.5 * 11 / 9600)
    assert line1.line.direction is None  # an adapter that turns the line round itself
    assert line2.line.gap_s == pytest.approx(0.005)  # as configured
    direction = line2.line.direction
    assert direction is not None
    assert direction.delay_before_tx_s == pytest.approx(0.001)
    assert direction.delay_after_tx_s == pytest.approx(0.002)


def test_a_drive_takes_its_address_as_unit_id_and_its_models_poll_groups_unless_told() -> None:
    pump1, fan3 = settings().drives
    assert (pump1.unit_id, pump1.model, pump1.timeout_s, pump1.retries) == (1, "gd20", None, None)
    assert pump1.poll_groups == get_profile("gd20").poll_groups
    assert not pump1.asks_for_polls
    assert (fan3.unit_id, fan3.retries) == (13, 0)
    assert fan3.timeout_s == pytest.approx(0.15)
    (fast,) = fan3.poll_groups
    assert (fast.name, fast.start, fast.count, fast.interval_s) == ("fast", 0x2100, 3, 0.25)
    assert fan3.asks_for_polls


def test_without_mqtt_or_the_console_only_drives_that_ask_are_polled() -> None:
    plain = settings()
    assert (plain.mqtt, plain.console, plain.metrics) == (None, None, None)
    assert [plain.polled(d) for d in plain.drives] == [False, True]
    with_mqtt = settings(FILE + "mqtt: {host: 10.0.0.5}\n")
    assert [with_mqtt.polled(d) for d in with_mqtt.drives] == [True, True]
    assert settings(FILE + "mqtt: {host: 10.0.0.5, enabled: false}\n").mqtt is None


def test_the_mqtt_client_id_is_the_gateways_own_unless_given() -> None:
    mqtt = settings(FILE + "mqtt: {host: 10.0.0.5}\n").mqtt
    assert mqtt is not None
    assert mqtt.client_id == "invt-gateway-hall2"
    assert mqtt.servers == (("10.0.0.5", 1883),)
    given = settings(FILE + "mqtt: {host: 10.0.0.5, client_id: cabinet-a}\n").mqtt
    assert given is not None
    assert given.client_id == "cabinet-a"


def test_the_store_lives_in_the_state_directory_and_forwards_only_with_mqtt(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv(ENV_STATE_DIRECTORY, f"{tmp_path}:/var/lib/other")  # systemd's list
    store = settings().store
    assert store.path == str(tmp_path / "events-hall2.db")  # one per gateway_id
    assert store.shared_path == str(tmp_path / "events.db")  # the default of earlier releases
    assert not store.forwarding
    assert settings(FILE + "mqtt: {host: 10.0.0.5}\n").store.forwarding
    given = settings(FILE + "storage: {path: /srv/plant.db}\n").store
    assert (given.path, given.shared_path) == ("/srv/plant.db", None)


def test_the_log_level_is_pythons_name_for_it() -> None:
    assert settings(FILE + "logging: {level: debug}\n").log_level == "DEBUG"


def test_the_configuration_shown_masks_every_secret_and_keeps_the_rest() -> None:
    text = FILE + "mqtt: {host: 10.0.0.5, username: plant, password: hunter2}\n"
    shown = settings(text).shown_configuration()
    assert shown["mqtt"]["password"] == MASK
    assert shown["mqtt"]["username"] == "plant"
    assert shown["mqtt"]["host"] == "10.0.0.5"
    assert shown["buses"][0]["timeout_ms"] == 250
    assert shown["console"]["users"] == []
    assert "hunter2" not in repr(shown)
