"""Home Assistant MQTT discovery: the entities each drive shows in Home Assistant. No I/O.

Each drive is a device with sensors (state, fault, frequency, current, voltages, power, speed:
those its profile's telemetry holds; a device file's points with their units and classes, a
binary sensor for each bool or bit point, and a number for each writable numeric point and a
switch for each writable coil when commands are enabled; a problem binary sensor per limit alarm
of `drives[].alarms`), buttons for the run and stop commands its profile takes and a number for
the frequency set-point (those two only when commands are enabled). The gateway itself is a
device too (its connection state), the one drives are reached "via".
Entities are available when both the gateway and the drive are.

Ids are built from `gateway_id` and the drive's name, so two gateways on one broker never claim
each other's entities.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Final

from gateway import __version__
from gateway.mqtt.topics import Topics
from gateway.profile import DriveProfile
from gateway.profile.limit_alarms import Side, alarm_name
from gateway.profile.point_types import Kind, TypedPoint
from gateway.settings import DriveSettings, MqttSettings

MAX_SETPOINT_HZ: Final = 630.0
"""The highest P00.03 (max. output frequency) of any Goodrive: no set-point entity goes above."""

ON_STATE: Final = "{{ value_json.state }}"
TWO_STATE: Final = (Kind.BOOL, Kind.BIT)
"""A device's points Home Assistant shows as binary sensors (on, off), not as sensors."""


@dataclass(frozen=True, slots=True)
class Sensor:
    key: str
    name: str
    unit: str | None = None
    device_class: str | None = None
    icon: str | None = None
    state_class: str | None = "measurement"
    """Home Assistant's state class where the sensor has a unit (or the device file says)."""


SENSORS: Final = (
    Sensor("state", "State", icon="mdi:state-machine"),
    Sensor("fault_description", "Fault", icon="mdi:alert-circle-outline"),
    Sensor("output_frequency_hz", "Output frequency", "Hz", "frequency"),
    Sensor("output_current_a", "Output current", "A", "current"),
    Sensor("output_voltage_v", "Output voltage", "V", "voltage"),
    Sensor("bus_voltage_v", "Bus voltage", "V", "voltage"),
    Sensor("output_power_pct", "Output power", "%", icon="mdi:flash"),
    Sensor("rotation_speed_rpm", "Rotation speed", "rpm", icon="mdi:rotate-right"),
)
BUTTONS: Final = (
    ("run_forward", "Run forward", "mdi:play"),
    ("run_reverse", "Run reverse", "mdi:play-outline"),
    ("stop", "Stop", "mdi:stop"),
    ("coast_stop", "Coast stop", "mdi:stop-circle-outline"),
    ("fault_reset", "Fault reset", "mdi:restore-alert"),
)


def discovery_messages(
    mqtt: MqttSettings,
    drives: Sequence[DriveSettings],
    topics: Topics,
    max_frequency_hz: Mapping[str, float] | None = None,
) -> list[tuple[str, str]]:
    """(topic, payload) of every entity's config message, to be published retained.

    The set-point's maximum is the drive's own P00.03 where `max_frequency_hz` has it (read at
    start), else its profile's factory P00.03."""
    read = max_frequency_hz or {}
    prefix = mqtt.discovery_prefix
    gateway_id = mqtt.gateway_id
    node = f"invt_{gateway_id}"
    origin = {"name": "invt-gateway", "sw_version": __version__}
    messages = [
        (
            f"{prefix}/binary_sensor/{node}/bridge_connection/config",
            _dump(
                {
                    "name": "Connection state",
                    "unique_id": f"{node}_bridge_connection",
                    "device_class": "connectivity",
                    "entity_category": "diagnostic",
                    "state_topic": topics.bridge_state,
                    "value_template": ON_STATE,
                    "payload_on": "online",
                    "payload_off": "offline",
                    "device": _bridge_device(node, gateway_id),
                    "origin": origin,
                }
            ),
        )
    ]
    commands = mqtt.commands_enabled
    for drive in drives:
        profile = drive.profile
        sensors = [sensor for sensor in SENSORS if sensor.key in profile.telemetry_keys]
        sensors += [_point_sensor(p) for p in profile.typed_points if p.kind not in TWO_STATE]
        if not sensors:
            continue  # nothing decoded to show (a generic device)
        common = {
            "availability": [
                {"topic": topics.bridge_state, "value_template": ON_STATE},
                {"topic": topics.availability(drive.name), "value_template": ON_STATE},
            ],
            "availability_mode": "all",
            "device": {
                "identifiers": [f"{node}_{drive.name}"],
                "name": drive.name,
                "manufacturer": profile.manufacturer,
                "model": profile.display_name,
                "via_device": node,
            },
            "origin": origin,
        }
        entity = f"{node}_{drive.name}"
        for sensor in sensors:
            payload: dict[str, Any] = {
                **common,
                "name": sensor.name,
                "unique_id": f"{entity}_{sensor.key}",
                "state_topic": topics.drive_state(drive.name),
                "value_template": f"{{{{ value_json.{sensor.key} }}}}",
            }
            if sensor.unit is not None:
                payload["unit_of_measurement"] = sensor.unit
                payload["state_class"] = sensor.state_class
            elif sensor.state_class is not None:
                payload["state_class"] = sensor.state_class
            if sensor.device_class is not None:
                payload["device_class"] = sensor.device_class
            if sensor.icon is not None:
                payload["icon"] = sensor.icon
            messages.append(
                (f"{prefix}/sensor/{node}/{drive.name}_{sensor.key}/config", _dump(payload))
            )
        messages += _alarm_sensors(prefix, node, drive, common, topics)
        messages += _point_binary_sensors(prefix, node, drive.name, common, topics, profile)
        if commands:
            messages += _point_numbers(prefix, node, drive.name, common, topics, profile)
        if not commands or not profile.commands:
            continue
        for command, name, icon in BUTTONS:
            if command not in profile.commands:
                continue
            payload = {
                **common,
                "name": name,
                "unique_id": f"{entity}_{command}",
                "command_topic": topics.set(drive.name),
                "payload_press": json.dumps({"command": command}),
                "icon": icon,
            }
            messages.append(
                (f"{prefix}/button/{node}/{drive.name}_{command}/config", _dump(payload))
            )
        setpoint = {
            **common,
            "name": "Frequency set-point",
            "unique_id": f"{entity}_frequency_setpoint",
            "command_topic": topics.set(drive.name),
            "command_template": '{"frequency_hz": {{ value }}}',
            "state_topic": topics.drive_state(drive.name),
            "value_template": "{{ value_json.set_frequency_hz }}",
            "min": 0,
            "max": min(read.get(drive.name, profile.max_frequency_hz), MAX_SETPOINT_HZ),
            "step": 0.01,
            "mode": "box",
            "unit_of_measurement": "Hz",
            "device_class": "frequency",
        }
        messages.append(
            (f"{prefix}/number/{node}/{drive.name}_frequency_setpoint/config", _dump(setpoint))
        )
    return messages


def _point_binary_sensors(
    prefix: str,
    node: str,
    drive: str,
    common: dict[str, Any],
    topics: Topics,
    profile: DriveProfile,
) -> list[tuple[str, str]]:
    """A binary sensor for each bool or bit point (a sensor would show True and False)."""
    messages = []
    for point in profile.typed_points:
        if point.kind not in TWO_STATE:
            continue
        payload = {
            **common,
            "name": point.name.replace("_", " ").capitalize(),
            "unique_id": f"{node}_{drive}_{point.name}",
            "state_topic": topics.drive_state(drive),
            "value_template": f"{{{{ 'ON' if value_json.{point.name} else 'OFF' }}}}",
        }
        if point.device_class is not None:
            payload["device_class"] = point.device_class
        topic = f"{prefix}/binary_sensor/{node}/{drive}_{point.name}/config"
        messages.append((topic, _dump(payload)))
    return messages


def _alarm_sensors(
    prefix: str, node: str, drive: DriveSettings, common: dict[str, Any], topics: Topics
) -> list[tuple[str, str]]:
    """A problem binary sensor per limit alarm of a drive (`drives[].alarms`), on its flag."""
    messages = []
    for key, limit in drive.alarms.items():
        sides: tuple[tuple[Side, float | None], ...] = (("high", limit.high), ("low", limit.low))
        for side, at in sides:
            if at is None:
                continue
            flag = alarm_name(key, side)
            payload = {
                **common,
                "name": f"Alarm {key} {side}",
                "unique_id": f"{node}_{drive.name}_{flag}",
                "device_class": "problem",
                "state_topic": topics.drive_state(drive.name),
                "value_template": f"{{{{ 'ON' if value_json.{flag} else 'OFF' }}}}",
            }
            topic = f"{prefix}/binary_sensor/{node}/{drive.name}_{flag}/config"
            messages.append((topic, _dump(payload)))
    return messages


def _point_sensor(point: TypedPoint) -> Sensor:
    """A device file's point as a sensor: its unit and classes as the file gives them."""
    name = point.name.replace("_", " ").capitalize()
    return Sensor(
        point.name, name, point.unit or None, point.device_class, state_class=point.state_class
    )


def _point_numbers(
    prefix: str,
    node: str,
    drive: str,
    common: dict[str, Any],
    topics: Topics,
    profile: DriveProfile,
) -> list[tuple[str, str]]:
    """A number entity for each writable numeric point, a switch for each writable coil,
    written through `<drive>/set`."""
    messages = []
    for point in profile.typed_points:
        if point.writable and point.kind is Kind.BOOL:
            messages.append(_switch(prefix, node, drive, common, topics, point))
        if not point.writable or point.kind in (Kind.STRING, Kind.ENUM, Kind.BOOL):
            continue
        payload = {
            **common,
            "name": point.name.replace("_", " ").capitalize(),
            "unique_id": f"{node}_{drive}_{point.name}_set",
            "command_topic": topics.set(drive),
            "command_template": f'{{"point": "{point.name}", "value": {{{{ value }}}}}}',
            "state_topic": topics.drive_state(drive),
            "value_template": f"{{{{ value_json.{point.name} }}}}",
            "mode": "box",
            "min": -1e9,
            "max": 1e9,
            "step": "any",
        }
        if point.unit:
            payload["unit_of_measurement"] = point.unit
        messages.append((f"{prefix}/number/{node}/{drive}_{point.name}/config", _dump(payload)))
    return messages


def _switch(
    prefix: str, node: str, drive: str, common: dict[str, Any], topics: Topics, point: TypedPoint
) -> tuple[str, str]:
    payload = {
        **common,
        "name": point.name.replace("_", " ").capitalize(),
        "unique_id": f"{node}_{drive}_{point.name}_set",
        "command_topic": topics.set(drive),
        "payload_on": json.dumps({"point": point.name, "value": True}),
        "payload_off": json.dumps({"point": point.name, "value": False}),
        "state_topic": topics.drive_state(drive),
        "value_template": f"{{{{ 'ON' if value_json.{point.name} else 'OFF' }}}}",
        "state_on": "ON",
        "state_off": "OFF",
    }
    return f"{prefix}/switch/{node}/{drive}_{point.name}/config", _dump(payload)


def _bridge_device(node: str, gateway_id: str) -> dict[str, Any]:
    return {
        "identifiers": [node],
        "name": f"INVT gateway {gateway_id}",
        "manufacturer": "invt-gateway",
        "sw_version": __version__,
    }


def _dump(payload: dict[str, Any]) -> str:
    return json.dumps(payload, separators=(",", ":"))
