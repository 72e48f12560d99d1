"""A drive's limit alarms on a real broker: an output current ramped across its limit, jittering
on the way, raises one `alarm_raised` and one `alarm_cleared` event, with the value and the
limit; the state carries the alarm's flag and Home Assistant gets a problem binary sensor."""

from __future__ import annotations

import asyncio

from tests.support import running_gateway
from tests.support.mosquitto import Mosquitto, mqtt_probe, unique_base_topic
from tests.support.mosquitto import mosquitto as mosquitto
from tests.support.mqtt_setup import FAST_POLL, mqtt_config, simulated_line

RAMP_A = (8.0, 9.0, 10.0, 11.0, 12.0, 11.0, 10.0, 9.0, 8.0, 7.0)
STEP_S = 0.7
"""Two polls of the running values (every 300 ms) at each step."""


async def test_a_ramp_across_the_limit_raises_and_clears_one_alarm(mosquitto: Mosquitto) -> None:
    base = unique_base_topic()
    drive = {
        "name": "pump1",
        "address": 1,
        "model": "gd350",
        "poll": FAST_POLL,
        "alarms": {
            "output_current_a": {"high": 10.0, "hysteresis": 1.5},  # a 10 A motor's rated current
            "bus_voltage_v": {"low": 430.0, "high": 780.0, "hysteresis": 10.0},
        },
    }
    with simulated_line(addresses=(1,)) as line:
        line.set_output_current(1, RAMP_A[0], jitter_a=0.3)
        config = mqtt_config(line.path, mosquitto, base, drives=[drive])
        async with mqtt_probe(mosquitto, f"{base}/#") as probe, running_gateway(config):
            state = await probe.wait_for(f"{base}/pump1", lambda s: "output_current_a" in s)
            assert state.json()["output_current_a_high_alarm"] is False
            assert state.json()["bus_voltage_v_low_alarm"] is False

            for amps in RAMP_A:
                line.set_output_current(1, amps, jitter_a=0.3)
                await asyncio.sleep(STEP_S)

            events = [
                m.json()
                for m in probe.on(f"{base}/bridge/event")
                if m.json()["type"].startswith("alarm_")
            ]
            assert [e["type"] for e in events] == ["alarm_raised", "alarm_cleared"]
            raised, cleared = (e["data"] for e in events)
            assert raised["drive"] == "pump1"
            assert raised["point"] == "output_current_a"
            assert (raised["limit"], raised["threshold"]) == ("high", 10.0)
            assert raised["value"] > 10.0
            assert cleared["value"] < 10.0 - 1.5
            flags = [m.json().get("output_current_a_high_alarm") for m in probe.on(f"{base}/pump1")]
            assert True in flags
            assert flags[-1] is False


async def test_home_assistant_gets_a_problem_binary_sensor_per_alarm(
    mosquitto: Mosquitto,
) -> None:
    base = unique_base_topic()
    prefix = f"{base}-ha"
    drive = {
        "name": "pump1",
        "address": 1,
        "model": "gd350",
        "alarms": {"bus_voltage_v": {"low": 430.0, "high": 780.0}},
    }
    with simulated_line(addresses=(1,)) as line:
        config = mqtt_config(line.path, mosquitto, base, drives=[drive], discovery_prefix=prefix)
        sensors = f"{prefix}/binary_sensor/invt_test"
        async with mqtt_probe(mosquitto, f"{sensors}/#") as probe, running_gateway(config):
            low = await probe.wait_for(f"{sensors}/pump1_bus_voltage_v_low_alarm/config")
            await probe.wait_for(f"{sensors}/pump1_bus_voltage_v_high_alarm/config")
    config_payload = low.json()
    assert config_payload["device_class"] == "problem"
    assert config_payload["state_topic"] == f"{base}/pump1"
    assert "bus_voltage_v_low_alarm" in config_payload["value_template"]
