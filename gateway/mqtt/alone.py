"""At start, before the bridge's own connection: is another gateway live on our base topic, or
with our gateway id?

Two gateways that share a base topic overwrite each other's retained state and each answers the
other's commands; two with one client id throw each other off the broker, for ever; two with
one gateway id share their Home Assistant entities (discovery topics and unique ids derive from
it), so either one's stop or start-up clean-up removes the other's. All are a copied
configuration (or a second demo beside the first), found here once rather than as flapping
states and vanished entities later: the retained `<base>/bridge/state` says "online" while its
gateway is connected (its last will says "offline" when it is gone), with the gateway's id and
client id. Refused (`BrokerShared`, exit code 4), before anything is published:

- "online" with another gateway id: a live gateway that is not us;
- "online" with our gateway id and another client id: a second instance of us (a demo's client
  id is its own each run). Our own client id there is our previous run (killed, its will not
  yet out): it is taken over as usual;
- our gateway id's discovery config of the gateway device (`.../invt_<id>/bridge_connection/
  config`) naming another base topic's `bridge/state`, which says "online" with our gateway id:
  a copy of us lives there (a service's copied configuration has our client id too: the base
  topic tells it from our previous run). A reload's check passes its running bridge's own.

The listed servers are asked in turn until one answers (a cluster's node that is down refuses at
once). None answering within `CHECK_BUDGET_S` is not waited for: the gateway starts, and the
bridge connects when it can (Modbus-TCP never waits for MQTT). A reload that would start the
bridge again on other MQTT settings asks the same question first (`Application.reload`).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging

import aiomqtt

from gateway.errors import BrokerShared, TlsSettingsError
from gateway.mqtt.connection import (
    MQTT_3_1_1,
    SUBSCRIBE_QOS,
    make_client,
    read_loss,
    server_name,
    tls_context,
)
from gateway.mqtt.topics import Topics
from gateway.settings import MqttSettings

log = logging.getLogger(__name__)

CHECK_BUDGET_S = 3.0
"""Connecting and reading the retained states; past it the check is given up, not the start."""
RETAINED_WAIT_S = 1.0
"""How long a topic may stay silent after subscribing before it is taken to keep nothing (the
broker sends what it keeps right away)."""


async def check_alone(mqtt: MqttSettings, topics: Topics, running: Topics | None = None) -> None:
    """Raises BrokerShared when another gateway is live on our base topic, or another
    instance with our gateway id anywhere on the broker. `running`: a reload's bridge, still
    connected (its "online" is ours, whatever its base topic and client id)."""
    try:
        async with asyncio.timeout(CHECK_BUDGET_S):
            server, states = await _first_answer(mqtt, topics)
    except (TimeoutError, aiomqtt.MqttError, TlsSettingsError) as exc:
        log.info(
            "MQTT: %s not checked for another gateway on %s: %s",
            ", ".join(server_name(server) for server in mqtt.servers),
            topics.base,
            str(exc) or type(exc).__name__,
        )
        return
    for topic, state in states.items():
        if running is not None and topic == running.bridge_state:
            continue
        refusal = _refusal(mqtt, topics, topic, state)
        if refusal is not None:
            where = state.get("server", server_name(server))
            raise BrokerShared(f"{refusal} on the broker {where}")


def _refusal(
    mqtt: MqttSettings, topics: Topics, topic: str, state: dict[str, object]
) -> str | None:
    """Why a retained `bridge/state` (ours, or that of another base topic where our gateway id
    publishes its entities) forbids us to start; None: it doesn't."""
    if state.get("state") != "online":
        return None
    other, client_id = state.get("gateway_id"), state.get("client_id")
    if topic == topics.bridge_state:
        if other is not None and other != mqtt.gateway_id:
            return (
                f"gateway {other!r} (client id {client_id!r}) is online with mqtt.base_topic "
                f"{topics.base!r}: give each gateway its own gateway_id and mqtt.base_topic"
            )
        if other is None or client_id in (None, mqtt.client_id):
            return None  # an older release's (no identity), or our previous run
    elif other != mqtt.gateway_id:
        return None  # the entities' base topic has another gateway now: they are stale
    base = topic.removesuffix("/bridge/state")
    return (
        f"gateway {mqtt.gateway_id!r} is online already (client id {client_id!r}, "
        f"mqtt.base_topic {base!r}): another instance of this gateway (a second demo?) would "
        "take over its Home Assistant entities; give this one its own gateway_id and "
        "mqtt.base_topic (a second demo: --mqtt-port with a free port starts a broker of its own)"
    )


async def _first_answer(
    mqtt: MqttSettings, topics: Topics
) -> tuple[tuple[str, int], dict[str, dict[str, object]]]:
    """The retained states that say who is live (`_retained_states`) through the first of
    `mqtt.servers` that answers, and which one: a cluster's node that is down refuses at once,
    and the next one is asked (a gateway started again while its first node is dead is still
    checked). MqttError when none answers."""
    failures = []
    for server in mqtt.servers:
        try:
            return server, await _retained_states(mqtt, topics, server)
        except aiomqtt.MqttError as exc:
            failures.append(f"{server_name(server)}: {str(exc) or type(exc).__name__}")
    raise aiomqtt.MqttError("; ".join(failures))


async def _retained_states(
    mqtt: MqttSettings, topics: Topics, server: tuple[str, int]
) -> dict[str, dict[str, object]]:
    """The retained `bridge/state` of our base topic and, when our gateway id's entities name
    another base topic, that one's too: by topic (none where nothing, or no JSON, is kept)."""
    # 3.1.1: every broker tried speaks it, so no attempt is spent on finding the protocol.
    tls = tls_context(mqtt)
    identifier = f"{mqtt.client_id}-check"
    client = make_client(mqtt, topics, tls, server, MQTT_3_1_1, identifier=identifier, will=False)
    entities = gateway_entity_topic(mqtt.discovery_prefix, mqtt.gateway_id)
    try:
        async with client:
            found = await _retained(client, [topics.bridge_state, entities])
            states = {topics.bridge_state: found.get(topics.bridge_state)}
            entities_state = (found.get(entities) or {}).get("state_topic")
            if isinstance(entities_state, str) and entities_state != topics.bridge_state:
                states[entities_state] = (await _retained(client, [entities_state])).get(
                    entities_state
                )
    finally:
        read_loss(client)
    return {topic: state for topic, state in states.items() if state is not None}


def gateway_entity_topic(prefix: str, gateway_id: str) -> str:
    """The discovery config of the gateway's own device (its connection state): its
    `state_topic` is the `bridge/state` of the base topic the gateway id last published on."""
    return f"{prefix}/binary_sensor/invt_{gateway_id}/bridge_connection/config"


async def _retained(client: aiomqtt.Client, wanted: list[str]) -> dict[str, dict[str, object]]:
    """The retained JSON objects on `wanted`, by topic: the broker sends what it keeps right
    after the subscription, so a topic still silent after `RETAINED_WAIT_S` keeps none."""
    found: dict[str, dict[str, object]] = {}
    heard: set[str] = set()
    await client.subscribe([(topic, SUBSCRIBE_QOS) for topic in wanted])
    try:
        async with asyncio.timeout(RETAINED_WAIT_S):
            async for message in client.messages:
                topic = str(message.topic)
                heard.add(topic)
                payload = message.payload
                if isinstance(payload, bytes | bytearray):
                    with contextlib.suppress(ValueError):
                        value = json.loads(payload)
                        if isinstance(value, dict):
                            found[topic] = value
                if heard >= set(wanted):
                    break
    except TimeoutError:
        pass
    return found
