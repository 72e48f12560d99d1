"""Retained commands never run, however they come; an empty payload is nobody's command.

Under MQTT 3.1.1 a broker clears the retain flag of a message it delivers to a live subscriber,
so a retained `stop` published while the gateway is connected looked fresh and ran. The bridge
speaks MQTT 5 where the broker does (Mosquitto 2) and subscribes with retain-as-published: the flag
survives, the command is refused (`retained`), and cleared from the broker so that it doesn't run
for the next subscriber. With a 3.1.1-only broker (our demo broker) the bridge falls back.
"""

from __future__ import annotations

import asyncio
import time

from gateway.instruments.embedded_broker import EmbeddedBroker
from gateway.mqtt.connection import MQTT_3_1_1, MQTT_5
from gateway.profile.states import RunState
from gateway.settings import runtime_settings
from tests.support import free_port, present, running_gateway
from tests.support.mosquitto import Address, Mosquitto, mqtt_probe, unique_base_topic
from tests.support.mqtt_setup import mqtt_config, simulated_line


async def test_a_retained_command_published_while_connected_is_refused_and_cleared(
    mosquitto: Mosquitto,
) -> None:
    base = unique_base_topic()
    topic = f"{base}/pump1/set"
    with simulated_line() as line:
        config = mqtt_config(line.path, mosquitto, base)
        async with mqtt_probe(mosquitto, f"{base}/#") as probe, running_gateway(config) as app:
            await probe.wait_for(f"{base}/pump1/availability", lambda a: a["state"] == "online")
            assert present(app.mqtt).session.protocol == MQTT_5
            mark = len(probe.messages)
            await probe.publish(topic, {"command": "run_forward", "transaction": "t1"}, retain=True)
            response = await probe.wait_for(
                f"{topic}/response", lambda r: r["transaction"] == "t1", after=mark
            )
            assert response.json()["error"] == "retained"
            event = await probe.wait_for(
                f"{base}/bridge/event",
                lambda e: e["type"] == "retained_command_cleared",
                after=mark,
            )
            assert event.json()["data"]["topic"] == topic
            assert event.json()["data"]["drive"] == "pump1"
            with line.lock:
                assert line.drives[1].state(time.monotonic()) is RunState.STOPPED
        # Nothing is left retained on the broker: a new subscriber gets no command.
        async with mqtt_probe(mosquitto, topic) as late:
            await asyncio.sleep(0.5)  # asserting an absence: time for anything retained to arrive
            assert [m for m in late.messages if m.payload] == []


async def test_an_empty_payload_on_a_command_topic_is_ignored_quietly(
    mosquitto: Mosquitto,
) -> None:
    base = unique_base_topic()
    with simulated_line() as line:
        config = mqtt_config(line.path, mosquitto, base)
        async with mqtt_probe(mosquitto, f"{base}/#") as probe, running_gateway(config):
            await probe.wait_for(f"{base}/pump1/availability", lambda a: a["state"] == "online")
            mark = len(probe.messages)
            await probe.publish(f"{base}/pump1/set", "")
            await probe.publish(f"{base}/bridge/request/read_parameter", "")
            # A real command after them is answered: the empty ones got no answer at all.
            await probe.request(
                f"{base}/pump1/set", {"command": "stop"}, f"{base}/pump1/set/response"
            )
            answers = [m for m in probe.messages[mark:] if "response" in m.topic]
            assert len(answers) == 1


async def test_a_broker_that_speaks_only_mqtt_3_1_1_gets_3_1_1() -> None:
    # The demo's embedded broker speaks 3.1.1 only, as RabbitMQ's MQTT plugin does.
    broker = EmbeddedBroker("127.0.0.1", free_port())
    await broker.start()
    try:
        base = unique_base_topic()
        with simulated_line() as line:
            config = mqtt_config(line.path, Address("127.0.0.1", broker.port), base)
            async with running_gateway(config) as app:
                await asyncio.wait_for(present(app.mqtt).connected.wait(), 10)
                assert present(app.mqtt).session.protocol == MQTT_3_1_1
                assert present(app.mqtt).stats.connects == 1
                assert (
                    present(app.mqtt).stats.connect_failures == 0
                )  # refused 5, then 3.1.1 at once
                # A negotiation, not an error: no "last error 132" (MQTT 5's CONNACK code).
                assert present(app.mqtt).status().last_error is None
    finally:
        await broker.stop()


async def test_on_a_3_1_1_broker_a_command_retained_while_connected_runs_and_is_cleared() -> None:
    """Under 3.1.1 the broker hands a message retained while we are subscribed on without its
    retain flag: the command runs (as documented), and must not stay on the broker for the
    next subscriber. The demo's embedded broker speaks 3.1.1 only, as NATS and RabbitMQ do."""
    broker = EmbeddedBroker("127.0.0.1", free_port())
    await broker.start()
    address = Address("127.0.0.1", broker.port)
    try:
        base = unique_base_topic()
        topic = f"{base}/pump1/set"
        with simulated_line() as line:
            config = mqtt_config(line.path, address, base)
            async with mqtt_probe(address, f"{base}/#") as probe, running_gateway(config) as app:
                await probe.wait_for(f"{base}/pump1/availability", lambda a: a["state"] == "online")
                assert present(app.mqtt).session.protocol == MQTT_3_1_1
                mark = len(probe.messages)
                run = {"command": "run_forward", "transaction": "t1"}
                await probe.publish(topic, run, retain=True)
                response = await probe.wait_for(
                    f"{topic}/response", lambda r: r["transaction"] == "t1", after=mark
                )
                assert response.json()["status"] == "ok"  # it ran
                await probe.wait_for(topic, lambda p: p == "", after=mark)  # then cleared
                answers = [m for m in probe.messages[mark:] if m.topic == f"{topic}/response"]
                assert len(answers) == 1  # the clearing is nobody's command: no answer
        # Nothing is left retained on the broker: a new subscriber gets no command.
        async with mqtt_probe(address, topic) as late:
            await asyncio.sleep(0.5)  # asserting an absence: time for anything retained to arrive
            assert [m for m in late.messages if m.payload] == []
    finally:
        await broker.stop()


async def test_entities_no_longer_offered_are_removed_from_home_assistant(
    mosquitto: Mosquitto,
) -> None:
    base = unique_base_topic()
    prefix = f"{base}-ha"
    gateway_id = unique_base_topic("gw")
    node = f"invt_{gateway_id}"
    ghost = f"{prefix}/sensor/{node}/oldpump_output_frequency/config"
    other = f"{prefix}/sensor/invt_someone-else/pump9_output_frequency/config"
    with simulated_line() as line:
        async with mqtt_probe(mosquitto, f"{prefix}/#") as probe:
            # Left by a previous run (a drive since removed), and another gateway's entity.
            await probe.publish(ghost, {"name": "old pump"}, retain=True)
            await probe.publish(other, {"name": "someone else's"}, retain=True)
            config = mqtt_config(
                line.path, mosquitto, base, gateway_id=gateway_id, discovery_prefix=prefix
            )
            async with running_gateway(config) as app:
                await probe.wait_for(ghost, lambda p: p == "", timeout_s=10)  # cleared
                offered = present(app.mqtt).publisher.discovery_topics()
                assert ghost not in offered
            # Now with discovery off: every entity of this gateway goes, the other one stays.
            config = mqtt_config(
                line.path,
                mosquitto,
                base,
                gateway_id=gateway_id,
                discovery_prefix=prefix,
                homeassistant_discovery=False,
            )
            async with running_gateway(config):
                some = next(iter(offered))
                await probe.wait_for(some, lambda p: p == "", timeout_s=10)
        async with mqtt_probe(mosquitto, f"{prefix}/#") as late:
            await asyncio.sleep(0.5)  # asserting an absence: time for anything retained to arrive
            left = {m.topic for m in late.messages if m.payload}
        assert left == {other}


async def test_mqtt_is_in_the_metrics(mosquitto: Mosquitto) -> None:
    from gateway.config import MetricsConfig
    from tests.support.http import Scrape, http_get

    base = unique_base_topic()
    metrics_port = free_port()
    with simulated_line() as line:
        config = mqtt_config(line.path, mosquitto, base)
        metrics = MetricsConfig(enabled=True, host="127.0.0.1", port=metrics_port)
        config = config.model_copy(update={"metrics": metrics})
        async with mqtt_probe(mosquitto, f"{base}/#") as probe, running_gateway(config):
            await probe.wait_for(f"{base}/pump1/availability", lambda a: a["state"] == "online")
            set_topic, response = f"{base}/pump1/set", f"{base}/pump1/set/response"
            await probe.request(set_topic, {"command": "stop"}, response)
            await probe.request(set_topic, {"command": "warp"}, response)
            _, _, text = await http_get(metrics_port, "/metrics")
    m = Scrape(text)
    assert m("mqtt_connected") == 1
    assert m("mqtt_messages_published_total") > 5
    assert m("mqtt_messages_dropped_total") == 0
    assert m("mqtt_commands_total", status="ok") == 1
    statuses = {
        dict(labels)["status"]: value
        for (name, labels), value in m.samples.items()
        if name == "invt_gateway_mqtt_commands_total"
    }
    refused = {status: count for status, count in statuses.items() if status not in ("ok", "busy")}
    assert sum(refused.values()) == 1, statuses  # "warp": no such command


async def test_a_reload_restarts_the_bridge_with_new_mqtt_settings_and_drives(
    mosquitto: Mosquitto,
) -> None:
    """Live reload of the `mqtt` section and of drives: the bridge starts again with them."""
    base, new_base = unique_base_topic(), unique_base_topic()
    with simulated_line((1, 2)) as line:
        pump = {"name": "pump1", "address": 1, "model": "gd350"}
        fan = {"name": "fan2", "address": 2, "model": "gd20"}
        config = mqtt_config(line.path, mosquitto, base, drives=[pump, fan])
        async with mqtt_probe(mosquitto, "#") as probe, running_gateway(config) as app:
            await probe.wait_for(f"{base}/fan2/availability", lambda a: a["state"] == "online")
            # fan2 renamed to blower2: one removed, one added; and a new base topic.
            blower = {**fan, "name": "blower2"}
            new = mqtt_config(line.path, mosquitto, new_base, drives=[pump, blower])
            plan = await app.reload(runtime_settings(new))
            assert "mqtt" in plan.changed
            assert "MQTT topics of drives added or removed" in plan.changed
            assert "mqtt" not in " ".join(plan.restart_needed)
            mark = len(probe.messages)
            state = await probe.wait_for(f"{new_base}/blower2", lambda s: "state" in s, after=mark)
            assert state.json()["state"] == "stopped"
            answer = await probe.request(
                f"{new_base}/blower2/set", {"command": "stop"}, f"{new_base}/blower2/set/response"
            )
            assert answer["status"] == "ok"
            refused = await probe.request(
                f"{new_base}/bridge/request/read_parameter",
                {"drive": "fan2", "parameter": "P00.11"},
                f"{new_base}/bridge/response/read_parameter",
            )
            assert refused["error"] == "unknown_drive"
            # The old tree says offline: nobody serves it any more.
            await probe.wait_for(f"{base}/bridge/state", lambda s: s["state"] == "offline")
