"""A redundant box's role on MQTT (`redundancy:` with `mqtt:`): both boxes, whatever their role,
publish it retained on `<base_topic>/bridge/redundancy/<box>`, on a connection of their own
(client id `<client_id>-<box>`: the two boxes share the bridge's), with a last will that says
`offline`. It is all a standby publishes: the drives' states, events and commands are the
active box's bridge's (`gateway.app.LineHandover` runs it only there).

    {"box": "gw-a", "role": "standby", "asked": "standby", "health": "ok", "peer": "gw-b",
     "last_change": {...}, "line_silent_s": 0.04, "heard_requests": 3118, ...}

Published on every role change and every `REFRESH_S` (the line's silence, heard counts).

On the same connection, the box follows what the active tells (`gateway.mqtt.told`): its
drives' faults, the memory its poller starts from when this box takes over, and its Sparkplug
node's bdSeq (in the active's own announcement), which this box's node counts on from.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
from collections.abc import Callable, Sequence
from typing import Any, Final

import aiomqtt

from gateway.backoff import Backoff
from gateway.errors import TlsSettingsError
from gateway.mqtt.connection import make_client, tls_context
from gateway.mqtt.told import Follower
from gateway.mqtt.topics import Topics
from gateway.settings import MqttSettings

log = logging.getLogger(__name__)

REFRESH_S: Final = 30.0
BYE_S: Final = 1.0
"""At stop, how long the last publish ("offline") may take."""


def role_topic(base_topic: str, box: str) -> str:
    return f"{base_topic}/bridge/redundancy/{box}"


class RoleAnnouncer:
    """Publishes `status()` (with `"box"`), retained, from `run` until cancelled."""

    def __init__(
        self,
        mqtt: MqttSettings,
        box: str,
        status: Callable[[], dict[str, Any]],
        followed: Sequence[Follower] = (),
    ) -> None:
        self.mqtt = mqtt
        self.followed = tuple(followed)
        self.box = box
        self.topic = role_topic(mqtt.base_topic, box)
        self._status = status
        self._changed = asyncio.Event()
        self.published = 0

    def changed(self) -> None:
        """The role changed: publish now (a `Redundancy` listener)."""
        self._changed.set()

    def _payload(self, role: str | None = None) -> bytes:
        status = {"box": self.box, **self._status()}
        if role is not None:
            status = {"box": self.box, "role": role}
        return json.dumps(status, sort_keys=True, separators=(",", ":")).encode()

    async def run(self) -> None:
        backoff = Backoff(1.0, 30.0)
        while True:
            try:
                await self._connected_once()
            except (aiomqtt.MqttError, OSError, TlsSettingsError) as exc:
                log.info("redundancy: role not on MQTT: %s; trying again", exc)
            await asyncio.sleep(backoff.next_delay())

    async def _connected_once(self) -> None:
        mqtt = self.mqtt
        tls = tls_context(mqtt)
        will = aiomqtt.Will(self.topic, self._payload("offline"), qos=1, retain=True)
        last: Exception | None = None
        for server in mqtt.servers:
            client = make_client(
                mqtt,
                Topics(mqtt.base_topic),
                tls,
                server,
                identifier=f"{mqtt.client_id}-{self.box}",
                last_will=will,
            )
            try:
                async with client:
                    await self._connected(client)
            except aiomqtt.MqttError as exc:
                last = exc
        if last is not None:
            raise last

    async def _connected(self, client: aiomqtt.Client) -> None:
        if not self.followed:
            await self._publish_until_cancelled(client, None)
            return
        topics = [topic for follower in self.followed for topic in follower.topics]
        await client.subscribe([(topic, 1) for topic in topics])
        following = asyncio.create_task(self._follow(client), name="redundancy:told")
        try:
            await self._publish_until_cancelled(client, following)
        finally:
            following.cancel()
            with contextlib.suppress(asyncio.CancelledError, aiomqtt.MqttError):
                await following

    async def _follow(self, client: aiomqtt.Client) -> None:
        try:
            async for message in client.messages:
                payload = message.payload
                if isinstance(payload, bytes | bytearray):
                    for follower in self.followed:
                        follower.take(str(message.topic), bytes(payload))
        finally:
            self._changed.set()  # the connection is gone: the publishing loop sees it at once

    async def _publish_until_cancelled(
        self, client: aiomqtt.Client, following: asyncio.Task[None] | None
    ) -> None:
        try:
            while True:
                if following is not None and following.done():
                    raise aiomqtt.MqttError("the role connection was lost")
                self._changed.clear()
                await client.publish(self.topic, self._payload(), qos=1, retain=True)
                self.published += 1
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(self._changed.wait(), REFRESH_S)
        except asyncio.CancelledError:
            # Stopped (the gateway stops): say so, rather than leave the last role standing.
            with contextlib.suppress(aiomqtt.MqttError, TimeoutError):
                await asyncio.wait_for(
                    client.publish(self.topic, self._payload("offline"), qos=1, retain=True),
                    BYE_S,
                )
            raise
