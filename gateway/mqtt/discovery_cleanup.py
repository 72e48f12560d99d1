"""Home Assistant entities this gateway published before and offers no longer: removed.

Discovery configs are retained on the broker: a drive taken out of the configuration, commands
disabled, or discovery turned off would leave its entities behind in Home Assistant for ever
("ghosts"). Once per start, a short side connection subscribes to this gateway's own discovery
topics (`<prefix>/<component>/invt_<gateway_id>/<object>/config`: no other gateway's), takes the
retained configs the broker hands over, and clears (an empty retained publish) each one the
gateway doesn't offer now. A broker that delivers retained messages only to exact-topic
subscriptions (RabbitMQ's MQTT plugin) hands over nothing here: there, ghosts stay.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Collection

import aiomqtt

from gateway.mqtt.connection import SUBSCRIBE_QOS, read_loss

log = logging.getLogger(__name__)

COLLECT_S = 1.0
"""How long the broker's retained configs may take to arrive after subscribing."""


def own_discovery_topics(prefix: str, gateway_id: str) -> str:
    """The subscription that matches every discovery config of this gateway, and no other's."""
    return f"{prefix}/+/invt_{gateway_id}/+/config"


async def remove_stale_entities(
    client: aiomqtt.Client, pattern: str, offered: Collection[str], collect_s: float = COLLECT_S
) -> list[str]:
    """Clear the retained configs under `pattern` that are not in `offered`; which were."""
    found: set[str] = set()
    try:
        async with client:
            await client.subscribe(pattern, qos=SUBSCRIBE_QOS)
            try:
                async with asyncio.timeout(collect_s):
                    async for message in client.messages:
                        if message.payload:  # an empty one is a config already cleared
                            found.add(str(message.topic))
            except TimeoutError:
                pass
            stale = sorted(found - set(offered))
            # Our own clearings would come back to us on the pattern (at QoS 0, which we don't
            # answer): Mosquitto sent each just before the clearing's PUBACK, and the PUBACK came
            # about 40 ms late (a delayed TCP acknowledgement, measured), a clearing each; a test
            # that stopped the gateway after one found the rest still there. Nothing more to hear.
            await client.unsubscribe(pattern)
            for topic in stale:
                await client.publish(topic, b"", qos=1, retain=True)
    finally:
        read_loss(client)
    if stale:
        log.info(
            "MQTT: removed %d Home Assistant entities this gateway no longer offers", len(stale)
        )
    return stale
