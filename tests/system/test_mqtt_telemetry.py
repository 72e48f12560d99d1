"""Telemetry out: drive state, faults, availability and Home Assistant discovery on a real broker,
from the whole gateway polling simulated drives on a pty."""

from __future__ import annotations

import asyncio

import pytest

from gateway.errors import BusClosed
from gateway.profile.invt import STATE_WORD_1
from tests.support import TcpClient, eventually, running_gateway
from tests.support.mosquitto import Mosquitto, mqtt_probe, unique_base_topic
from tests.support.mqtt_setup import mqtt_config, simulated_line


async def test_state_fault_and_running_values_are_decoded(mosquitto: Mosquitto) -> None:
    base = unique_base_topic()
    with simulated_line() as line:
        config = mqtt_config(line.path, mosquitto, base)
        async with mqtt_probe(mosquitto, f"{base}/#") as probe, running_gateway(config):
            bridge = await probe.wait_for(f"{base}/bridge/state")
            assert bridge.json()["state"] == "online"
            assert (await probe.wait_for(f"{base}/pump1/availability")).json() == {
                "state": "online"
            }
            state = (
                await probe.wait_for(f"{base}/pump1", lambda s: "output_frequency_hz" in s)
            ).json()
            assert state["state"] == "stopped"
            assert state["state_word_1"] == 3
            assert state["fault_code"] == 0
            assert state["fault_name"] == "none"
            assert state["command_source"] == "communication"
            assert state["output_frequency_hz"] == 0.0
            assert isinstance(state["bus_voltage_v"], float)
            assert "output_current_a" in state
            assert state["last_seen"].endswith("Z")
            retained = [m for m in probe.on(f"{base}/pump1")]
            assert retained  # published retained: a late subscriber gets it at once
            async with mqtt_probe(mosquitto, f"{base}/fan2") as late:
                first = await late.wait_for(f"{base}/fan2")
                assert first.retain
                assert first.json()["state"] == "stopped"

            mark = len(probe.messages)
            line.inject_fault(1, 11)  # OL1 motor overload
            event = await probe.wait_for(
                f"{base}/bridge/event", lambda e: e["type"] == "fault_raised", after=mark
            )
            assert event.json()["data"] | {"time": None} == {
                "drive": "pump1",
                "fault_code": 11,
                "fault_name": "OL1",
                "fault_description": "OL1: motor overload",
                "time": None,
            }
            faulty = await probe.wait_for(
                f"{base}/pump1", lambda s: s["state"] == "fault", after=mark
            )
            assert faulty.json()["fault_code"] == 11
            assert faulty.json()["fault_name"] == "OL1"

            mark = len(probe.messages)
            line.clear_fault(1)
            cleared = await probe.wait_for(
                f"{base}/bridge/event", lambda e: e["type"] == "fault_cleared", after=mark
            )
            assert cleared.json()["data"]["fault_code"] == 11
            await probe.wait_for(f"{base}/pump1", lambda s: s["fault_code"] == 0, after=mark)


async def test_unknown_fault_code_shows_its_number(mosquitto: Mosquitto) -> None:
    base = unique_base_topic()
    with simulated_line() as line:
        config = mqtt_config(line.path, mosquitto, base)
        async with mqtt_probe(mosquitto, f"{base}/#") as probe, running_gateway(config):
            await probe.wait_for(f"{base}/fan2")
            line.inject_fault(2, 250)
            state = await probe.wait_for(f"{base}/fan2", lambda s: s["fault_code"] == 250)
            assert state.json()["fault_name"] == "250"
            assert state.json()["fault_description"] == "unknown fault 250"


async def test_dead_drive_goes_offline_and_comes_back(mosquitto: Mosquitto) -> None:
    base = unique_base_topic()
    with simulated_line() as line:
        # The bus probes an offline drive at most every second here: it is found back quickly.
        config = mqtt_config(
            line.path, mosquitto, base, bus={"probe_max_s": 1.0}, publish_interval_s=0.5
        )
        async with mqtt_probe(mosquitto, f"{base}/#") as probe, running_gateway(config) as app:
            await probe.wait_for(f"{base}/fan2/availability", lambda a: a["state"] == "online")
            mark = len(probe.messages)
            line.set_dead(2, True)
            offline = await probe.wait_for(
                f"{base}/bridge/event", lambda e: e["type"] == "drive_offline", after=mark
            )
            assert offline.json()["data"]["drive"] == "fan2"
            availability = await probe.wait_for(
                f"{base}/fan2/availability", lambda a: a["state"] == "offline", after=mark
            )
            assert availability.retain is False or availability.json() == {"state": "offline"}
            # The healthy drive keeps being published, and SCADA still reads it.
            tcp = await TcpClient.connect(app.tcp.port)
            try:
                assert await tcp.read(1, STATE_WORD_1) == [3]
            finally:
                await tcp.close()
            mark = len(probe.messages)
            await probe.wait_for(f"{base}/pump1", after=mark)

            mark = len(probe.messages)
            line.set_dead(2, False)
            online = await probe.wait_for(
                f"{base}/bridge/event",
                lambda e: e["type"] == "drive_online",
                timeout_s=15,
                after=mark,
            )
            assert online.json()["data"]["drive"] == "fan2"
            await probe.wait_for(
                f"{base}/fan2/availability", lambda a: a["state"] == "online", after=mark
            )


async def test_offline_drive_is_polled_with_backoff(mosquitto: Mosquitto) -> None:
    base = unique_base_topic()
    with simulated_line() as line:
        line.set_dead(2, True)
        config = mqtt_config(line.path, mosquitto, base)
        async with mqtt_probe(mosquitto, f"{base}/#") as probe, running_gateway(config) as app:
            await probe.wait_for(f"{base}/fan2/availability", lambda a: a["state"] == "offline")
            fan2 = app.poller.drives["fan2"]
            polls_before = fan2.polls
            await asyncio.sleep(3.0)  # the thing under test: polls counted over a fixed window
            # Polled normally, its two groups (150 ms, 300 ms) would be read 30 times in 3 s.
            assert fan2.polls - polls_before <= 8
            assert fan2.offline_backoff >= 2


async def test_home_assistant_discovery(mosquitto: Mosquitto) -> None:
    base = unique_base_topic()
    prefix = unique_base_topic("ha")
    with simulated_line() as line:
        config = mqtt_config(line.path, mosquitto, base, discovery_prefix=prefix)
        async with mqtt_probe(mosquitto, f"{prefix}/#") as probe, running_gateway(config):
            frequency_topic = f"{prefix}/sensor/invt_test/pump1_output_frequency_hz/config"
            frequency = (await probe.wait_for(frequency_topic)).json()
            assert frequency["state_topic"] == f"{base}/pump1"
            assert frequency["unit_of_measurement"] == "Hz"
            assert frequency["value_template"] == "{{ value_json.output_frequency_hz }}"
            assert frequency["device"]["identifiers"] == ["invt_test_pump1"]
            # The set-point is the last of pump1's entities: everything before it is there.
            setpoint = (
                await probe.wait_for(f"{prefix}/number/invt_test/pump1_frequency_setpoint/config")
            ).json()
            assert setpoint["command_topic"] == f"{base}/pump1/set"
            assert setpoint["command_template"] == '{"frequency_hz": {{ value }}}'
            topics = {m.topic for m in probe.messages}
            for key in (
                "state",
                "fault_description",
                "output_current_a",
                "bus_voltage_v",
                "output_power_pct",
            ):
                assert f"{prefix}/sensor/invt_test/pump1_{key}/config" in topics
            assert f"{prefix}/button/invt_test/pump1_run_forward/config" in topics
            assert f"{prefix}/button/invt_test/pump1_stop/config" in topics

            mark = len(probe.messages)
            await probe.publish(f"{prefix}/status", "online")
            await probe.wait_for(frequency_topic, after=mark)


async def test_discovery_can_be_turned_off(mosquitto: Mosquitto) -> None:
    base = unique_base_topic()
    prefix = unique_base_topic("ha")
    with simulated_line() as line:
        config = mqtt_config(
            line.path, mosquitto, base, discovery_prefix=prefix, homeassistant_discovery=False
        )
        async with (
            mqtt_probe(mosquitto, f"{prefix}/#", f"{base}/#") as probe,
            running_gateway(config),
        ):
            await probe.wait_for(f"{base}/pump1")
            await probe.publish(f"{prefix}/status", "online")
            await asyncio.sleep(0.5)  # asserting an absence: the window a republish would come in
            assert not [
                m
                for m in probe.messages
                if m.topic.startswith(prefix + "/") and m.topic != f"{prefix}/status"
            ]


async def test_failed_polls_short_of_the_bus_offline_after_keep_the_drive_available(
    mosquitto: Mosquitto,
) -> None:
    """Only the bus decides that a drive is offline (after `offline_after` failed requests,
    SCADA's counted too), and /health says what the bus says: a few failed polls must not turn
    the drive's MQTT availability offline while the bus still has it online."""
    base = unique_base_topic()
    with simulated_line() as line:
        config = mqtt_config(line.path, mosquitto, base, bus={"offline_after": 50})
        async with mqtt_probe(mosquitto, f"{base}/#") as probe, running_gateway(config) as app:
            await probe.wait_for(f"{base}/pump1/availability", lambda a: a["state"] == "online")
            pump1 = app.poller.drives["pump1"]
            mark = len(probe.messages)
            line.set_dead(1, True)
            await eventually(lambda: pump1.failed_polls >= 5, within_s=10.0)
            line.set_dead(1, False)
            assert not app.buses["line1"].health.is_offline(1)
            await probe.wait_for(f"{base}/pump1", after=mark)
            await eventually(lambda: pump1.failed_polls == 0, 10.0, "answered again")
            later = probe.messages[mark:]
            availability = [m.json() for m in later if m.topic == f"{base}/pump1/availability"]
            assert {"state": "offline"} not in availability
            assert not [m.json() for m in later if m.topic == f"{base}/bridge/event"]


async def test_shutting_down_is_no_poll_failure(mosquitto: Mosquitto) -> None:
    """Polls cut off by the shutdown fail with BusClosed: not the drive's doing, not counted,
    no drive said to be offline on the way out."""
    base = unique_base_topic()
    with simulated_line() as line:
        config = mqtt_config(line.path, mosquitto, base)
        async with mqtt_probe(mosquitto, f"{base}/#") as probe:
            async with running_gateway(config) as app:
                await probe.wait_for(f"{base}/fan2/availability", lambda a: a["state"] == "online")
                failures = app.poller.poll_failures
                mark = len(probe.messages)
            assert app.poller.poll_failures == failures
            assert not [m for m in probe.messages[mark:] if m.topic.endswith("/availability")]
            with pytest.raises(BusClosed):
                await app.router.execute(1, bytes.fromhex("03 2100 0001"), client="test")
