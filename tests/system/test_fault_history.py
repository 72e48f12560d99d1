"""Fault history: five faults of a running drive, each with the running values at its raise,
read back over MQTT (`bridge/request/fault_history`) after the gateway restarted; the commands
that ran the drive are events too."""

from __future__ import annotations

from typing import Any

from tests.support import present, running_gateway
from tests.support.mosquitto import Mosquitto, MqttProbe, mqtt_probe, unique_base_topic
from tests.support.mqtt_setup import mqtt_config, simulated_line

CODES = (2, 11, 15, 23, 40)
"""OUt2, OL1, OH1, bCE, STO on the GD350: five different trips."""


async def request(probe: MqttProbe, base: str, operation: str, payload: dict[str, Any]) -> Any:
    return await probe.request(
        f"{base}/bridge/request/{operation}", payload, f"{base}/bridge/response/{operation}"
    )


async def test_five_faults_with_snapshots_read_back_after_a_restart(mosquitto: Mosquitto) -> None:
    base = unique_base_topic()
    events = f"{base}/bridge/event"
    with simulated_line() as line:
        config = mqtt_config(line.path, mosquitto, base, homeassistant_discovery=False)
        async with mqtt_probe(mosquitto, f"{base}/#") as probe, running_gateway(config):
            await probe.wait_for(f"{base}/pump1/availability", lambda a: a["state"] == "online")
            for code in CODES:
                mark = len(probe.messages)
                run = {"command": "run_forward", "frequency_hz": 30.0}
                response = await probe.request(
                    f"{base}/pump1/set", run, f"{base}/pump1/set/response"
                )
                assert response["status"] == "ok", response
                command = await probe.wait_for(events, lambda e: e["type"] == "command", after=mark)
                assert command.json()["data"] | {"transaction": None} == {
                    "drive": "pump1",
                    "source": "mqtt",
                    "command": "run_forward",
                    "frequency_hz": 30.0,
                    "result": "ok",
                    "transaction": None,
                }
                await probe.wait_for(
                    f"{base}/pump1", lambda s: s.get("output_frequency_hz", 0) > 0, after=mark
                )
                line.inject_fault(1, code)
                await probe.wait_for(
                    events,
                    lambda e, c=code: e["type"] == "fault_raised" and e["data"]["fault_code"] == c,
                    after=mark,
                )
                line.clear_fault(1)
                await probe.wait_for(events, lambda e: e["type"] == "fault_cleared", after=mark)

        # A restart: a new gateway on the same store.
        async with mqtt_probe(mosquitto, f"{base}/#") as probe, running_gateway(config) as app:
            await present(app.mqtt).connected.wait()  # subscribed: a request now is heard
            answer = await request(probe, base, "fault_history", {"drive": "pump1", "limit": 20})
            two = await request(probe, base, "fault_history", {"drive": "pump1", "limit": 2})
            none = await request(probe, base, "fault_history", {"drive": "fan2"})
            unknown = await request(probe, base, "fault_history", {"drive": "pump9"})
            bad = await request(probe, base, "fault_history", {"drive": "pump1", "limit": 0})

    assert answer["status"] == "ok", answer
    faults = answer["data"]["faults"]
    assert answer["data"]["drive"] == "pump1"
    assert [f["code"] for f in faults] == list(reversed(CODES))  # newest first
    assert faults[-1]["name"] == "OUt2"
    assert faults[-1]["description"] == "OUt2: inverter unit phase V protection"
    for fault in faults:
        assert fault["raised"] < fault["cleared"]
        assert fault["duration_s"] > 0
        snapshot = fault["snapshot"]
        assert snapshot["output_frequency_hz"] > 0  # it was running when it tripped
        for key in ("output_current_a", "bus_voltage_v", "state_word_1", "state_word_2"):
            assert key in snapshot, (key, snapshot)
    assert [f["raised"] for f in faults] == sorted((f["raised"] for f in faults), reverse=True)
    assert two["data"]["faults"] == faults[:2]
    assert none["data"] == {"drive": "fan2", "faults": []}
    assert unknown["status"] == "error"
    assert unknown["error"] == "unknown_drive"
    assert bad["error"] == "invalid_request"


async def test_a_fault_that_cleared_while_the_gateway_was_down_is_closed(
    mosquitto: Mosquitto,
) -> None:
    base = unique_base_topic()
    events = f"{base}/bridge/event"
    with simulated_line() as line:
        config = mqtt_config(line.path, mosquitto, base, homeassistant_discovery=False)
        async with mqtt_probe(mosquitto, f"{base}/#") as probe, running_gateway(config):
            await probe.wait_for(f"{base}/pump1/availability", lambda a: a["state"] == "online")
            line.inject_fault(1, 11)
            await probe.wait_for(events, lambda e: e["type"] == "fault_raised")
        line.clear_fault(1)  # reset on the keypad while the gateway was down
        async with mqtt_probe(mosquitto, f"{base}/#") as probe, running_gateway(config) as app:
            await probe.wait_for(f"{base}/pump1", lambda s: s.get("fault_code") == 0)
            await present(app.mqtt).connected.wait()
            for _ in range(50):  # the history is written by the store's thread, a moment later
                answer = await request(probe, base, "fault_history", {"drive": "pump1"})
                (fault,) = answer["data"]["faults"]
                if fault["cleared"] is not None:
                    break
    assert fault["code"] == 11
    assert fault["cleared"] is not None
    assert fault["duration_s"] > 0


async def test_a_fault_still_there_after_a_restart_is_not_raised_again(
    mosquitto: Mosquitto,
) -> None:
    """One row per event: a trip that outlives a restart of the gateway was raised once, and
    its clearing after the restart is the next event, not a second raise."""
    base = unique_base_topic()
    events = f"{base}/bridge/event"
    with simulated_line() as line:
        config = mqtt_config(line.path, mosquitto, base, homeassistant_discovery=False)
        async with mqtt_probe(mosquitto, f"{base}/#") as probe, running_gateway(config):
            await probe.wait_for(f"{base}/pump1/availability", lambda a: a["state"] == "online")
            line.inject_fault(1, 11)
            first = await probe.wait_for(events, lambda e: e["type"] == "fault_raised")
        async with mqtt_probe(mosquitto, f"{base}/#") as probe, running_gateway(config) as app:
            await probe.wait_for(f"{base}/pump1", lambda s: s.get("fault_code") == 11)
            line.clear_fault(1)
            await probe.wait_for(events, lambda e: e["type"] == "fault_cleared")
            raised_ids = {
                m.json()["id"]
                for m in probe.messages
                if m.topic == events and m.json()["type"] == "fault_raised"
            }
            stored = await app.events.recent_events(50)
    # At most the first run's own event again (store-and-forward may resend it), never a new one.
    assert raised_ids <= {first.json()["id"]}
    assert [e.id for e in stored if e.type == "fault_raised"] == [first.json()["id"]]
