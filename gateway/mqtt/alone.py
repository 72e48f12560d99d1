"""At start, before the bridge's own connection: is another gateway live on our base topic?

Two gateways that share a base topic overwrite each other's retained state and each answers the
other's commands; two with one client id throw each other off the broker, for ever. Both are
a copied configuration, found here once rather than as flapping states later: the retained
`<base>/bridge/state` says "online" while its gateway is connected (its last will says
"offline" when it is gone), with the gateway's id and client id. "Online" with another gateway
id is a live gateway that is not us: the start is refused (`BrokerShared`, exit code 4); the
client id derives from the gateway id, so a copied one is caught with it. Our own gateway id
there is our previous run (killed, its will not yet out): it is taken over as usual.

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

CHECK_BUDGET_S = 2.0
"""Connecting and reading the retained state; past it the check is given up, not the start."""


async def check_alone(mqtt: MqttSettings, topics: Topics) -> None:
    """Raises BrokerShared when another gateway is live on our base topic."""
    try:
        async with asyncio.timeout(CHECK_BUDGET_S):
            server, state = await _first_answer(mqtt, topics)
    except (TimeoutError, aiomqtt.MqttError, TlsSettingsError) as exc:
        log.info(
            "MQTT: %s not checked for another gateway on %s: %s",
            ", ".join(server_name(server) for server in mqtt.servers),
            topics.base,
            str(exc) or type(exc).__name__,
        )
        return
    if state is None or state.get("state") != "online":
        return
    other = state.get("gateway_id")
    if other is None or other == mqtt.gateway_id:
        # An older release's (no identity), or our own: a previous run, or a demo beside
        # another (a client id of its own, the same gateway id by design).
        return
    raise BrokerShared(
        f"gateway {other!r} (client id {state.get('client_id')!r}) is online on the broker "
        f"{state.get('server', server_name(server))} with mqtt.base_topic {topics.base!r}: "
        "give each gateway its own gateway_id and mqtt.base_topic"
    )


async def _first_answer(
    mqtt: MqttSettings, topics: Topics
) -> tuple[tuple[str, int], dict[str, object] | None]:
    """The retained `bridge/state` through the first of `mqtt.servers` that answers, and which
    one: a cluster's node that is down refuses at once, and the next one is asked (a gateway
    started again while its first node is dead is still checked). MqttError when none answers."""
    failures = []
    for server in mqtt.servers:
        try:
            return server, await _retained_state(mqtt, topics, server)
        except aiomqtt.MqttError as exc:
            failures.append(f"{server_name(server)}: {str(exc) or type(exc).__name__}")
    raise aiomqtt.MqttError("; ".join(failures))


async def _retained_state(
    mqtt: MqttSettings, topics: Topics, server: tuple[str, int]
) -> dict[str, object] | None:
    """The retained `bridge/state`, or None when there is none (or it isn't JSON)."""
    # 3.1.1: every broker tried speaks it, so no attempt is spent on finding the protocol.
    tls = tls_context(mqtt)
    identifier = f"{mqtt.client_id}-check"
    client = make_client(mqtt, topics, tls, server, MQTT_3_1_1, identifier=identifier, will=False)
    try:
        async with client:
            await client.subscribe(topics.bridge_state, qos=SUBSCRIBE_QOS)
            try:
                async with asyncio.timeout(CHECK_BUDGET_S / 2):
                    async for message in client.messages:
                        payload = message.payload
                        if isinstance(payload, bytes | bytearray):
                            with contextlib.suppress(ValueError):
                                state = json.loads(payload)
                                return state if isinstance(state, dict) else None
                        return None
            except TimeoutError:
                return None  # nothing retained: the broker has sent what it keeps at once
    finally:
        read_loss(client)
    return None
