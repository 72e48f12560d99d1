"""Which connection carries the event log to the broker: the session's, or one of its own.

By default the events go out on the session's connection, beside the states and the commands.
With `mqtt.own_events_connection` they get a connection of their own to the same broker, made
while the session's lasts (client id `<client_id>-events`, no last will), and made again, with
jittered and capped backoff, each time it is lost; the session's connection goes on meanwhile.

Why apart: a NATS cluster stores every QoS 1 message in a replicated stream. For seconds after
a node's death that stream may have no leader; the node then holds the publishing connection
for 4 s and closes it. An event (QoS 1, never dropped) caught in that would take the drives'
states and the commands down with it; apart, only the events wait, in the store, until the
connection is made again (nothing is lost: each is marked delivered once acknowledged).
"""

from __future__ import annotations

import asyncio
import logging

import aiomqtt

from gateway.backoff import Backoff
from gateway.mqtt.connection import read_loss
from gateway.mqtt.publisher import Publisher
from gateway.mqtt.session import RECONNECT_INITIAL_S, Session
from gateway.tasks import side_by_side

log = logging.getLogger(__name__)

PURPOSE = "events"
"""The own connection's client id is `<client_id>-events`."""
STOP_BUDGET_S = 0.3
"""For the forwarding to end once its connection is lost (within the bridge's budget)."""


class EventLink:
    def __init__(self, session: Session, publisher: Publisher) -> None:
        self.session = session
        self.publisher = publisher
        self.losses = 0
        """Own connections lost or refused (with `own_events_connection`)."""

    async def run(self, client: aiomqtt.Client) -> None:
        """Forward the events for as long as the session's connection (`client`) lasts."""
        if not self.session.mqtt.own_events_connection:
            await self.publisher.forward_events(client)
            return
        backoff = Backoff(RECONNECT_INITIAL_S, self.session.mqtt.reconnect_max_s)
        failures = 0
        while True:
            own = self.session.side_client(PURPOSE)
            try:
                async with own:
                    failures = 0
                    backoff.reset()
                    await side_by_side(
                        {
                            "mqtt:events:forward": self.publisher.forward_events(own),
                            "mqtt:events:watch": until_lost(own),
                        },
                        STOP_BUDGET_S,
                    )
            except* aiomqtt.MqttError as group:
                self.losses += 1
                failures += 1
                # Loudly once, then quietly: the session's own log says when its broker is gone.
                level = logging.WARNING if failures == 1 else logging.DEBUG
                log.log(
                    level,
                    "MQTT: the events' own connection: %s; again with backoff",
                    group.exceptions[0],
                )
            finally:
                read_loss(own)
            await asyncio.sleep(backoff.next_delay())


async def until_lost(client: aiomqtt.Client) -> None:
    """Raise MqttError as soon as `client`'s connection is lost: aiomqtt's message iterator is
    what sees that (a publish waiting for its PUBACK would wait out its timeout). Nothing is
    subscribed on the events' connection, so nothing comes."""
    async for _ in client.messages:
        pass
