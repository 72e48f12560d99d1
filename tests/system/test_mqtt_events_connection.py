"""`mqtt.own_events_connection` and `mqtt.publish_qos: 0`, what a NATS cluster needs.

The events go out on a connection of their own (`<client_id>-events`), still QoS 1 and marked
delivered once acknowledged; the drives' retained states and the command answers at QoS 0.
Losing the events' connection leaves the session's up (on NATS that loss is a node closing the
connection of a QoS 1 message it could not store yet), and loses no event.
"""

from __future__ import annotations

from typing import Any

import aiomqtt

from tests.support import eventually, present, running_gateway
from tests.support.mosquitto import BrokerProxy, Mosquitto, mqtt_probe, unique_base_topic
from tests.support.mqtt_setup import mqtt_config, simulated_line

APART: dict[str, Any] = {"own_events_connection": True, "publish_qos": 0}


async def test_events_go_on_their_own_connection_at_qos_1_states_and_answers_at_qos_0(
    mosquitto: Mosquitto,
) -> None:
    base = unique_base_topic()
    with simulated_line() as line:
        config = mqtt_config(line.path, mosquitto, base, **APART)
        async with mqtt_probe(mosquitto, f"{base}/#") as probe, running_gateway(config) as app:
            state = await probe.wait_for(f"{base}/fan2", lambda s: s["state"] == "stopped")
            assert state.qos == 0
            mark = len(probe.messages)
            line.inject_fault(2, 13)
            event = await probe.wait_for(
                f"{base}/bridge/event", lambda e: e["type"] == "fault_raised", after=mark
            )
            assert event.qos == 1
            assert event.json()["data"]["fault_code"] == 13
            await probe.publish(f"{base}/pump1/set", {"command": "stop", "transaction": "t1"})
            answer = await probe.wait_for(
                f"{base}/pump1/set/response", lambda r: r["transaction"] == "t1", after=mark
            )
            assert (answer.qos, answer.json()["status"]) == (0, "ok")
            assert present(app.mqtt).stats.connects == 1
        # A late dashboard still reads the state, retained.
        async with mqtt_probe(mosquitto, f"{base}/fan2") as late:
            retained = await late.wait_for(f"{base}/fan2", lambda s: s["fault_code"] == 13)
            assert retained.retain
    assert " as invt-gateway-test-events " in mosquitto.log()


async def test_the_events_connection_lost_alone_leaves_the_session_up_and_loses_nothing(
    mosquitto: Mosquitto,
) -> None:
    base = unique_base_topic()
    with simulated_line() as line:
        config = mqtt_config(line.path, mosquitto, base, **APART)
        async with mqtt_probe(mosquitto, f"{base}/#") as probe, running_gateway(config) as app:
            await probe.wait_for(f"{base}/fan2", lambda s: s["state"] == "stopped")
            # Another client with the events' client id: the broker closes theirs.
            intruder = aiomqtt.Client(
                mosquitto.host,
                mosquitto.port,
                identifier=f"{present(app.mqtt).settings.client_id}-events",
            )
            async with intruder:
                await eventually(lambda: present(app.mqtt).event_link.losses >= 1, within_s=5.0)
            mark = len(probe.messages)
            line.inject_fault(2, 14)
            event = await probe.wait_for(
                f"{base}/bridge/event", lambda e: e["type"] == "fault_raised", after=mark
            )
            assert event.json()["data"]["fault_code"] == 14
            assert present(app.mqtt).stats.connects == 1  # the session's connection never dropped
            assert present(app.mqtt).session.connected.is_set()
            assert app.events.stats.events_dropped == 0


async def test_an_event_being_published_when_both_connections_break_is_not_lost(
    mosquitto: Mosquitto,
) -> None:
    base = unique_base_topic()
    async with BrokerProxy(mosquitto) as relay:
        with simulated_line() as line:
            config = mqtt_config(line.path, relay, base, **APART)
            async with (
                mqtt_probe(mosquitto, f"{base}/#") as probe,
                running_gateway(config) as app,
            ):
                await probe.wait_for(f"{base}/fan2", lambda s: s["state"] == "stopped")
                relay.freeze()
                mark = len(probe.messages)
                line.inject_fault(2, 13)
                await relay.wait_held(b"fault_raised")  # published; no acknowledgement comes
                relay.cut()
                event = await probe.wait_for(
                    f"{base}/bridge/event", lambda e: e["type"] == "fault_raised", after=mark
                )
                assert event.json()["data"]["fault_code"] == 13
                assert app.events.stats.events_dropped == 0
