"""Every entity the gateway offers Home Assistant passes Home Assistant's own rules, and so does
every state it publishes for them (`tests/support/home_assistant.py`: the rules, from its
source).

The demo's drives (GD350, GD20, GD200A), commands enabled, on a real Mosquitto: the State and
Fault sensors went out with `state_class: measurement` and carried text, which Home Assistant
refuses (they stayed unknown); the points' numbers went out with `step: "any"`, which its number
schema refuses outright.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import yaml

from gateway.config import parse_config
from gateway.instruments.commands.demo import demo_config_text
from gateway.instruments.simulator import SimulatedLine
from gateway.mqtt.discovery import discovery_messages
from gateway.mqtt.topics import Topics
from gateway.settings import runtime_settings
from tests.support import running_gateway
from tests.support.home_assistant import all_problems, component_of, config_problems
from tests.support.mosquitto import Mosquitto, mqtt_probe, unique_base_topic
from tests.support.mqtt_setup import FAST_POLL, MQTT_LINE, mqtt_config

METER = Path(__file__).resolve().parents[1] / "fixtures" / "devices" / "test_meter.yaml"


def demo_drives() -> list[dict[str, Any]]:
    """The demo configuration's drives, polled fast."""
    drives = yaml.safe_load(demo_config_text(None))["drives"]
    return [{**drive, "poll": FAST_POLL} for drive in drives]


async def test_every_entity_and_state_of_the_demo_passes_home_assistants_rules(
    mosquitto: Mosquitto,
) -> None:
    base, prefix = unique_base_topic(), unique_base_topic("ha")
    drives = demo_drives()
    models = {drive["address"]: drive["model"] for drive in drives}
    line_settings = {**MQTT_LINE, "addresses": tuple(models), "models": models}
    with SimulatedLine(**line_settings) as line:
        config = mqtt_config(line.path, mosquitto, base, drives=drives, discovery_prefix=prefix)
        async with (
            mqtt_probe(mosquitto, f"{base}/#", f"{prefix}/#") as probe,
            running_gateway(config),
        ):
            for drive in drives:
                name = drive["name"]
                await probe.wait_for(
                    f"{base}/{name}/availability", lambda a: a["state"] == "online"
                )
                await probe.wait_for(f"{base}/{name}", lambda s: "output_frequency_hz" in s)
            # A running drive too: its state and figures are what Home Assistant shows most.
            answer = await probe.request(
                f"{base}/pump1/set",
                {"command": "run_forward", "frequency_hz": 25.0},
                f"{base}/pump1/set/response",
            )
            assert answer["status"] == "ok", answer
            await probe.wait_for(f"{base}/pump1", lambda s: s["state"] == "running_forward")
    configs = {
        m.topic: json.loads(m.payload)
        for m in probe.messages
        if m.topic.startswith(f"{prefix}/") and m.payload
    }
    components = {component_of(topic) for topic in configs}
    assert {"sensor", "binary_sensor", "button", "number"} <= components, components
    states = [(m.topic, m.payload) for m in probe.messages if m.topic.startswith(f"{base}/")]
    assert all_problems(configs, states) == []
    # The two text sensors are offered, as text: no class, no unit.
    state_sensor = configs[f"{prefix}/sensor/invt_test/pump1_state/config"]
    assert not {"state_class", "unit_of_measurement", "device_class"} & state_sensor.keys()


def test_a_device_files_points_pass_home_assistants_rules() -> None:
    """Every kind of point (numbers, a string, an enumeration, bits, writable ones) as the
    discovery offers it: the string and the enumeration are text sensors, the writable
    numbers have a step Home Assistant takes."""
    text = (
        "gateway_id: test\nbuses: [{name: line1, port: /dev/null}]\n"
        "mqtt: {commands_enabled: true}\n"
        f"drives: [{{name: meter1, bus: line1, address: 7, model: 'file:{METER}'}}]\n"
    )
    settings = runtime_settings(parse_config(text))
    assert settings.mqtt is not None
    messages = discovery_messages(settings.mqtt, settings.drives, Topics("invt"))
    configs = {topic: json.loads(payload) for topic, payload in messages}
    problems = [
        f"{topic}: {problem}"
        for topic, config in configs.items()
        for problem in config_problems(component_of(topic), config)
    ]
    assert problems == []
    for point in ("serial", "mode"):
        sensor = configs[f"homeassistant/sensor/invt_test/meter1_{point}/config"]
        assert not {"state_class", "unit_of_measurement", "device_class"} & sensor.keys()
    setpoint = configs["homeassistant/number/invt_test/meter1_setpoint/config"]
    assert setpoint["step"] == 0.001  # an f32
    temperature = configs["homeassistant/number/invt_test/meter1_temperature/config"]
    assert temperature["step"] == 0.1  # its scale: one count
