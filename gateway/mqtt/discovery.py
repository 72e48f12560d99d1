"""Home Assistant MQTT discovery: the entities each drive shows in Home Assistant. No I/O.

Each drive is a device with sensors (state, fault, frequency, current, voltages, power, speed:
those its profile's telemetry holds; a device file's points with their units and classes, a
binary sensor for each bool or bit point, and a number for each writable numeric point and a
switch for each writable coil when commands are enabled; a problem binary sensor per limit
alarm, a drive's `drives[].alarms` and a device's points' `high`/`low`), buttons for the run and
stop commands its profile takes and a number for the frequency set-point (those two only when
commands are enabled). The gateway itself is a device too (its connection state), the one
drives are reached "via". Entities are available when both the gateway and the drive are.

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
from gateway.profile.limit_alarms import alarm_name, limit_sides
from gateway.profile.point_types import Kind, TypedPoint
from gateway.settings import DriveSettings, MqttSettings

MAX_SETPOINT_HZ: Final = 630.0
"""The highest P00.03 (max. output frequency) of any Goodrive: no set-point entity goes above."""

ON_STATE: Final = "{{ value_json.state }}"
TWO_STATE: Final = (Kind.BOOL, Kind.BIT)
"""A device's points Home Assistant shows as binary sensors (on, off), not as sensors."""


NON_NUMERIC_DEVICE_CLASSES: Final = frozenset({"date", "enum", "timestamp"})
"""Home Assistant's sensor device classes whose state is not a number
(homeassistant/components/sensor/const.py, `NON_NUMERIC_DEVICE_CLASSES`)."""


@dataclass(frozen=True, slots=True)
class Sensor:
    key: str
    name: str
    unit: str | None = None
    device_class: str | None = None
    icon: str | None = None
    state_class: str | None = "measurement"
    """Home Assistant's state class where the sensor has a unit (or the device file says)."""
    text: bool = False
    """Its state is text (a drive's state, a fault's description, a string or enum point).
    Home Assistant takes a state class, a unit or a numeric device class as the promise of a
    number, and refuses a text state on such a sensor (it stays unknown): a text sensor has
    none of them."""


SENSORS: Final = (
    Sensor("state", "State", icon="mdi:state-machine", text=True),
    Sensor("fault_description", "Fault", icon="mdi:alert-circle-outline", text=True),
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
    for drive in drives:
        messages += _drive_entities(mqtt, drive, topics, node, origin, read)
    return messages


@dataclass(frozen=True, slots=True)
class _Entities:
    """One drive's entities: where their configs go and what every one of them shares."""

    prefix: str
    node: str
    drive: str
    common: dict[str, Any]
    topics: Topics

    @property
    def state_topic(self) -> str:
        return self.topics.drive_state(self.drive)

    def config(
        self, component: str, key: str, fields: dict[str, Any], unique: str | None = None
    ) -> tuple[str, str]:
        """The one shape of every entity's config: the shared keys, its unique id (`key`
        unless `unique` says otherwise), its own `fields`."""
        payload = {**self.common, "unique_id": f"{self.node}_{self.drive}_{unique or key}"}
        payload.update(fields)
        return f"{self.prefix}/{component}/{self.node}/{self.drive}_{key}/config", _dump(payload)

    def binary_sensor(
        self, key: str, device_class: str | None, name: str | None = None
    ) -> tuple[str, str]:
        """A binary sensor on a true/false key of the state: a two-state point, an alarm."""
        fields: dict[str, Any] = {
            "name": name or _named(key),
            "state_topic": self.state_topic,
            "value_template": _on_off(key),
        }
        if device_class is not None:
            fields["device_class"] = device_class
        return self.config("binary_sensor", key, fields)


def _drive_entities(
    mqtt: MqttSettings,
    drive: DriveSettings,
    topics: Topics,
    node: str,
    origin: dict[str, Any],
    read: Mapping[str, float],
) -> list[tuple[str, str]]:
    profile = drive.profile
    sensors = [sensor for sensor in SENSORS if sensor.key in profile.telemetry_keys]
    sensors += [_point_sensor(p) for p in profile.typed_points if p.kind not in TWO_STATE]
    if not sensors:
        return []  # nothing decoded to show (a generic device)
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
    entities = _Entities(mqtt.discovery_prefix, node, drive.name, common, topics)
    messages = [_sensor(entities, sensor) for sensor in sensors]
    messages += _alarm_sensors(entities, drive)
    messages += [
        entities.binary_sensor(point.name, point.device_class)
        for point in profile.typed_points
        if point.kind in TWO_STATE  # a sensor would show True and False
    ]
    if not mqtt.commands_enabled:
        return messages
    messages += _point_numbers(entities, profile)
    if profile.commands:
        messages += _commands(entities, profile, read.get(drive.name, profile.max_frequency_hz))
    return messages


def _sensor(entities: _Entities, sensor: Sensor) -> tuple[str, str]:
    fields: dict[str, Any] = {
        "name": sensor.name,
        "state_topic": entities.state_topic,
        "value_template": f"{{{{ value_json.{sensor.key} }}}}",
    }
    if not sensor.text:
        fields.update(_numeric_classes(sensor))
    if sensor.icon is not None:
        fields["icon"] = sensor.icon
    return entities.config("sensor", sensor.key, fields)


def _numeric_classes(sensor: Sensor) -> dict[str, Any]:
    """A number's unit, state class and device class, as far as Home Assistant takes them: a
    non-numeric device class (a device file may name one) would make it read the number as
    text, and refuse the unit beside it; it is left out."""
    fields: dict[str, Any] = {}
    if sensor.unit is not None:
        fields["unit_of_measurement"] = sensor.unit
    if sensor.state_class is not None:
        fields["state_class"] = sensor.state_class
    if sensor.device_class is not None and sensor.device_class not in NON_NUMERIC_DEVICE_CLASSES:
        fields["device_class"] = sensor.device_class
    return fields


def _alarm_sensors(entities: _Entities, drive: DriveSettings) -> list[tuple[str, str]]:
    """A problem binary sensor per limit alarm, on its flag in the state: a drive's
    (`drives[].alarms`) and a device's (its points' `high`/`low`) alike."""
    return [
        entities.binary_sensor(alarm_name(key, side), "problem", name=f"Alarm {key} {side}")
        for key, limit in drive.alarms.items()
        for side, _ in limit_sides(limit)
    ]


def _commands(
    entities: _Entities, profile: DriveProfile, max_frequency_hz: float
) -> list[tuple[str, str]]:
    """The buttons of the commands the profile takes, and the frequency set-point."""
    command_topic = entities.topics.set(entities.drive)
    messages = [
        entities.config(
            "button",
            command,
            {
                "name": name,
                "command_topic": command_topic,
                "payload_press": json.dumps({"command": command}),
                "icon": icon,
            },
        )
        for command, name, icon in BUTTONS
        if command in profile.commands
    ]
    setpoint = {
        "name": "Frequency set-point",
        "command_topic": command_topic,
        "command_template": '{"frequency_hz": {{ value }}}',
        "state_topic": entities.state_topic,
        "value_template": "{{ value_json.set_frequency_hz }}",
        "min": 0,
        "max": min(max_frequency_hz, MAX_SETPOINT_HZ),
        "step": 0.01,
        "mode": "box",
        "unit_of_measurement": "Hz",
        "device_class": "frequency",
    }
    messages.append(entities.config("number", "frequency_setpoint", setpoint))
    return messages


def _point_sensor(point: TypedPoint) -> Sensor:
    """A device file's point as a sensor: its unit and classes as the file gives them (a
    string or an enumeration's words: a text sensor, whatever the file says)."""
    return Sensor(
        point.name,
        _named(point.name),
        point.unit or None,
        point.device_class,
        state_class=point.state_class,
        text=point.kind in (Kind.STRING, Kind.ENUM),
    )


def _point_numbers(entities: _Entities, profile: DriveProfile) -> list[tuple[str, str]]:
    """A number entity for each writable numeric point, a switch for each writable coil,
    written through `<drive>/set`."""
    messages = []
    command_topic = entities.topics.set(entities.drive)
    for point in profile.typed_points:
        if not point.writable or point.kind in (Kind.STRING, Kind.ENUM):
            continue
        unique = f"{point.name}_set"
        if point.kind is Kind.BOOL:
            switch = {
                "name": _named(point.name),
                "command_topic": command_topic,
                "payload_on": json.dumps({"point": point.name, "value": True}),
                "payload_off": json.dumps({"point": point.name, "value": False}),
                "state_topic": entities.state_topic,
                "value_template": _on_off(point.name),
                "state_on": "ON",
                "state_off": "OFF",
            }
            messages.append(entities.config("switch", point.name, switch, unique))
            continue
        number: dict[str, Any] = {
            "name": _named(point.name),
            "command_topic": command_topic,
            "command_template": f'{{"point": "{point.name}", "value": {{{{ value }}}}}}',
            "state_topic": entities.state_topic,
            "value_template": f"{{{{ value_json.{point.name} }}}}",
            "mode": "box",
            "min": -1e9,
            "max": 1e9,
            "step": _step(point),
        }
        if point.unit:
            number["unit_of_measurement"] = point.unit
        messages.append(entities.config("number", point.name, number, unique))
    return messages


MIN_STEP: Final = 0.001
"""The smallest step Home Assistant's MQTT number takes (homeassistant/components/mqtt/
number.py: `vol.Range(min=1e-3)`); it refuses a config with "any" (not a number) outright."""


def _step(point: TypedPoint) -> float:
    """A number's step: what one count of the register means (its scale), or a float's
    published decimals; never below Home Assistant's smallest."""
    if point.decimals is not None:
        step = 10.0**-point.decimals
    elif point.kind in (Kind.F32, Kind.F64):
        step = MIN_STEP
    else:
        step = abs(point.scale) or 1.0
    return max(step, MIN_STEP)


def _named(key: str) -> str:
    """A key as Home Assistant shows it: `output_current_a_high_alarm` → `Output current a...`."""
    return key.replace("_", " ").capitalize()


def _on_off(key: str) -> str:
    """Home Assistant's template for a true/false key of the state: ON or OFF."""
    return f"{{{{ 'ON' if value_json.{key} else 'OFF' }}}}"


def _bridge_device(node: str, gateway_id: str) -> dict[str, Any]:
    return {
        "identifiers": [node],
        "name": f"INVT gateway {gateway_id}",
        "manufacturer": "invt-gateway",
        "sw_version": __version__,
    }


def _dump(payload: dict[str, Any]) -> str:
    return json.dumps(payload, separators=(",", ":"))
