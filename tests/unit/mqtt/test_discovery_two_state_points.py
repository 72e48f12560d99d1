"""Home Assistant shows a device's bool and bit points as binary sensors (on, off), not as
sensors reading True and False; its numbers stay sensors."""

from __future__ import annotations

import json
from pathlib import Path

from gateway.config import parse_config
from gateway.mqtt.discovery import discovery_messages
from gateway.mqtt.topics import Topics
from gateway.settings import runtime_settings

METER = Path(__file__).resolve().parents[2] / "fixtures" / "devices" / "test_meter.yaml"


def entities() -> dict[str, dict[str, object]]:
    text = (
        "gateway_id: test\nbuses: [{name: line1, port: /dev/null}]\nmqtt: {}\n"
        f"drives: [{{name: meter1, bus: line1, address: 7, model: 'file:{METER}'}}]\n"
    )
    settings = runtime_settings(parse_config(text))
    assert settings.mqtt is not None
    messages = discovery_messages(settings.mqtt, settings.drives, Topics("invt"))
    return {topic: json.loads(payload) for topic, payload in messages}


def test_bool_and_bit_points_are_binary_sensors() -> None:
    found = entities()
    prefix = "homeassistant/binary_sensor/invt_test/meter1"
    for point in ("running", "tripped", "pump_on", "door_open"):
        assert f"{prefix}_{point}/config" in found
        assert f"homeassistant/sensor/invt_test/meter1_{point}/config" not in found
    door = found[f"{prefix}_door_open/config"]
    assert door["state_topic"] == "invt/meter1"
    assert door["value_template"] == "{{ 'ON' if value_json.door_open else 'OFF' }}"


def test_numbers_stay_sensors() -> None:
    assert "homeassistant/sensor/invt_test/meter1_energy_wh/config" in entities()
