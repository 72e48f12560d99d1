"""Home Assistant's own rules for MQTT discovery configs and the states they read, reproduced
from its source, so a test can hold every entity the gateway offers to them.

A shape check (the keys are there) passed sensors Home Assistant then showed as "unknown" for
ever: it refuses a text state on a sensor it takes for a number. The rules here are Home
Assistant's, as its source (home-assistant/core, 2024-2025) states them:

- homeassistant/components/sensor/__init__.py, `SensorEntity.state` and the module's
  `_numeric_state_expected`: a sensor whose device class is not one of
  `NON_NUMERIC_DEVICE_CLASSES` (sensor/const.py: date, enum, timestamp) and that has a state
  class, a unit of measurement or a device class "indicat[es] it has a numeric value"; a state
  that `int()`/`float()` can't read, or isn't finite, raises ValueError ("...however, it has the
  non-numeric value"). A non-numeric device class with a unit raises too; an enum sensor's state
  must be one of its `options`.
- homeassistant/components/mqtt/sensor.py, `validate_sensor_state_and_device_class_config`:
  `options` must not be empty, comes with no state class nor unit, and only with device class
  enum; `MqttSensor._update_state`: the rendered "None" is unknown, "" on a numeric sensor is
  ignored, a text state longer than 255 characters is refused (`check_state_too_long`,
  `MAX_LENGTH_STATE_STATE`).
- homeassistant/components/mqtt/number.py: `step` is a float of at least 1e-3, `min` < `max`;
  a state that is not a number is refused ("Payload ... is not a Number").
- binary_sensor and switch (mqtt/binary_sensor.py, mqtt/switch.py): the rendered state is
  `payload_on`/`payload_off` (`state_on`/`state_off` for a switch), "ON"/"OFF" by default.

Templates are rendered with Jinja2, Home Assistant's template engine; a key the state lacks
is an error here (Home Assistant logs a template warning and shows nothing).
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable
from typing import Any, Final

import jinja2

STATE_CLASSES: Final = frozenset({"measurement", "total", "total_increasing"})
NON_NUMERIC_DEVICE_CLASSES: Final = frozenset({"date", "enum", "timestamp"})
MAX_LENGTH_STATE: Final = 255
MIN_NUMBER_STEP: Final = 1e-3
PAYLOAD_NONE: Final = "None"
"""What a template renders for a null value: Home Assistant's "unknown"."""

_TEMPLATES: Final = jinja2.Environment(undefined=jinja2.StrictUndefined, autoescape=False)


def numeric_state_expected(config: dict[str, Any]) -> bool:
    """sensor/__init__.py `_numeric_state_expected`, on a discovery config's keys."""
    device_class = config.get("device_class")
    if device_class in NON_NUMERIC_DEVICE_CLASSES:
        return False
    if config.get("state_class") is not None or config.get("unit_of_measurement") is not None:
        return True
    if config.get("suggested_display_precision") is not None:
        return True
    return device_class is not None


def config_problems(component: str, config: dict[str, Any]) -> list[str]:
    """Why Home Assistant would refuse this discovery config (nothing: it takes it)."""
    problems = []
    if not config.get("unique_id"):
        problems.append("no unique_id")
    if component == "sensor":
        problems += _sensor_config_problems(config)
    if component == "number":
        step = config.get("step", 1)
        if not isinstance(step, int | float) or isinstance(step, bool) or step < MIN_NUMBER_STEP:
            problems.append(f"step {step!r} is not a number of at least {MIN_NUMBER_STEP}")
        if not config.get("min", 1) < config.get("max", 100):
            problems.append("min is not below max")
    return problems


def _sensor_config_problems(config: dict[str, Any]) -> list[str]:
    problems = []
    state_class = config.get("state_class")
    if state_class is not None and state_class not in STATE_CLASSES:
        problems.append(f"state_class {state_class!r} is not one of {sorted(STATE_CLASSES)}")
    device_class = config.get("device_class")
    if device_class in NON_NUMERIC_DEVICE_CLASSES and config.get("unit_of_measurement"):
        problems.append(f"a unit beside the non-numeric device class {device_class}")
    options = config.get("options")
    if options is not None:
        if not options:
            problems.append("an empty options list")
        if state_class or config.get("unit_of_measurement"):
            problems.append("options beside a state_class or unit")
        if device_class != "enum":
            problems.append(f"options with device class {device_class!r}, not enum")
    elif device_class == "enum":
        problems.append("device class enum without its options")
    return problems


def render(template: str, payload: bytes) -> str:
    """A value template on a state message, as Home Assistant renders it (to text)."""
    try:
        value_json = json.loads(payload)
    except ValueError:
        value_json = None
    return _TEMPLATES.from_string(template).render(value=payload.decode(), value_json=value_json)


def state_problem(component: str, config: dict[str, Any], payload: bytes) -> str | None:
    """Why Home Assistant would refuse (or show nothing for) this state of the entity."""
    template = config.get("value_template", "{{ value }}")
    try:
        state = render(template, payload)
    except jinja2.UndefinedError as exc:
        return f"{template} on {payload[:120]!r}: {exc}"
    if component == "sensor":
        return _sensor_state_problem(config, state)
    if component == "number":
        return None if state == PAYLOAD_NONE or _number(state) else f"{state!r} is not a number"
    if component in ("binary_sensor", "switch"):
        on, off = (
            ("state_on", "state_off") if component == "switch" else ("payload_on", "payload_off")
        )
        allowed = {config.get(on, "ON"), config.get(off, "OFF")}
        return None if state in allowed else f"{state!r} is not one of {sorted(allowed)}"
    return None


def _sensor_state_problem(config: dict[str, Any], state: str) -> str | None:
    if state == PAYLOAD_NONE:
        return None  # unknown: a value not read yet, which Home Assistant shows as such
    if numeric_state_expected(config):
        if not _number(state):
            return (
                f"{state!r} is not a number, where device class {config.get('device_class')!r}, "
                f"state class {config.get('state_class')!r} and unit "
                f"{config.get('unit_of_measurement')!r} promise one"
            )
        return None
    options = config.get("options")
    if options and state not in options:
        return f"{state!r} is not one of the options {options}"
    if not state:
        return "an empty state"
    if len(state) > MAX_LENGTH_STATE:
        return f"a state of {len(state)} characters (at most {MAX_LENGTH_STATE})"
    return None


def _number(text: str) -> bool:
    try:
        return math.isfinite(float(text))
    except ValueError:
        return False


def availability_problems(config: dict[str, Any], states: dict[str, bytes]) -> list[str]:
    """Each availability topic's last message must render to available or not available."""
    problems = []
    for entry in config.get("availability", []):
        payload = states.get(entry["topic"])
        if payload is None:
            problems.append(f"nothing on {entry['topic']}")
            continue
        state = render(entry.get("value_template", "{{ value }}"), payload)
        allowed = {
            entry.get("payload_available", "online"),
            entry.get("payload_not_available", "offline"),
        }
        if state not in allowed:
            problems.append(f"availability {entry['topic']}: {state!r} not in {sorted(allowed)}")
    return problems


def component_of(topic: str) -> str:
    """`<prefix>/<component>/<node>/<object>/config`'s component."""
    return topic.split("/")[-4]


def all_problems(
    configs: dict[str, dict[str, Any]], messages: Iterable[tuple[str, bytes]]
) -> list[str]:
    """Every config checked, and every state message checked against each entity reading it."""
    problems = [
        f"{topic}: {problem}"
        for topic, config in configs.items()
        for problem in config_problems(component_of(topic), config)
    ]
    last: dict[str, bytes] = {}
    for state_topic, payload in messages:
        if not payload:
            continue
        last[state_topic] = payload
        for topic, config in configs.items():
            if config.get("state_topic") != state_topic:
                continue
            problem = state_problem(component_of(topic), config, payload)
            if problem is not None:
                problems.append(f"{topic} on {payload[:200]!r}: {problem}")
    for topic, config in configs.items():
        problems += [f"{topic}: {p}" for p in availability_problems(config, last)]
    return problems
