"""A redundant box's role on MQTT (`redundancy:` with `mqtt:`): both boxes, whatever their role,
publish it retained on `<base_topic>/bridge/redundancy/<box>`, on a connection of their own
(client id `<client_id>-<box>`: the two boxes share the bridge's), with a last will that says
`offline`. It is all a standby publishes: the drives' states, events and commands are the
active box's bridge's (`gateway.app.LineHandover` runs it only there).

    {"box": "gw-a", "role": "standby", "asked": "standby", "health": "ok", "peer": "gw-b",
     "last_change": {...}, "line_silent_s": 0.04, "heard_requests": 3118, ...}

Published on every role change and every `REFRESH_S` (the line's silence, heard counts).
Beside it, retained on `<base_topic>/bridge/redundancy/<box>/config`, what the box runs of the
configuration both boxes must share, as one digest per key (`gateway.config.peer.
shared_digests`: no value, no secret), published at each connection and when it changes (a
reload); the announcement carries their digest in one (`config_digest`).

On the same connection, the box follows what the other tells (`gateway.mqtt.told`): the
active's drives' faults, the memory its poller starts from when this box takes over, its
Sparkplug node's bdSeq (in the active's own announcement), which this box's node counts on
from, and the other box's configuration digests, compared with its own
(`gateway.redundancy.peer_config`).

And while the box doesn't serve its lines (`forwards`), its own events go out on it too, to
`<base_topic>/bridge/event` like the bridge's (`forward_stored`: each once, with its `box` and
its own `time`): a box back as standby (restarted after a kill, its network back) hands over
the backlog it recorded while its broker was away. Nothing else of a standby's: the drives'
states belong to the active.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import json
import logging
from collections.abc import Callable, Coroutine, Mapping, Sequence
from typing import Any, Final

import aiomqtt

from gateway.backoff import Backoff
from gateway.errors import TlsSettingsError
from gateway.mqtt.connection import make_client, tls_context
from gateway.mqtt.publisher import forward_stored
from gateway.mqtt.told import CONFIG_LEVEL, Follower, ToldConfig
from gateway.mqtt.topics import Topics
from gateway.redundancy.peer_config import PeerConfig
from gateway.settings import MqttSettings
from gateway.store import EventStore
from gateway.tasks import cancel_and_wait

log = logging.getLogger(__name__)

REFRESH_S: Final = 30.0
BYE_S: Final = 1.0
"""At stop, how long the last publish ("offline") may take."""


def role_topic(base_topic: str, box: str) -> str:
    return f"{base_topic}/bridge/redundancy/{box}"


def dump(message: dict[str, Any]) -> bytes:
    return json.dumps(message, sort_keys=True, separators=(",", ":")).encode()


class RoleAnnouncer:
    """Publishes `status()` (with `"box"`), retained, from `run` until cancelled; with `peer`,
    what this box runs of the shared configuration beside it, and the other box's followed and
    compared; this box's own events while it doesn't serve its lines (`hand_events`)."""

    def __init__(
        self,
        mqtt: MqttSettings,
        box: str,
        status: Callable[[], dict[str, Any]],
        followed: Sequence[Follower] = (),
        peer: PeerConfig | None = None,
    ) -> None:
        self.mqtt = mqtt
        self.box = box
        self.topic = role_topic(mqtt.base_topic, box)
        self._status = status
        self._peer = peer
        if peer is not None:
            followed = (*followed, ToldConfig(mqtt.base_topic, box, self._peer_heard))
        self.followed = tuple(followed)
        self._events: EventStore | None = None
        self._forwards: Callable[[], bool] = lambda: False
        self._changed = asyncio.Event()
        self._backoff = Backoff(1.0, 30.0)
        """Reset at each connection: a broker back after a long outage is tried within 1 s."""
        self.published = 0

    def hand_events(self, events: EventStore, forwards: Callable[[], bool]) -> None:
        """`events`' undelivered events go out on this connection while `forwards()` (the box
        doesn't serve its lines: its bridge, which forwards them otherwise, doesn't run)."""
        self._events, self._forwards = events, forwards

    def changed(self) -> None:
        """The role changed: publish now (a `Redundancy` listener)."""
        self._changed.set()

    def reloaded(self) -> None:
        """This box runs another configuration (a reload): compared again, announced now."""
        if self._peer is not None:
            self._peer.reloaded()
        self._changed.set()

    def _peer_heard(self, box: str, digests: Mapping[str, str]) -> None:
        assert self._peer is not None
        self._peer.heard(box, digests)
        self._changed.set()  # the announcement says how they compare

    def _payload(self, role: str | None = None) -> bytes:
        if role is not None:
            return dump({"box": self.box, "role": role})
        status = {"box": self.box, **self._status()}
        if self._peer is not None:
            status["config_digest"] = _digest(self._peer.digests())
        return dump(status)

    async def run(self) -> None:
        while True:
            try:
                await self._connected_once()
            except (aiomqtt.MqttError, OSError, TlsSettingsError) as exc:
                log.info("redundancy: role not on MQTT: %s; trying again", exc)
            await asyncio.sleep(self._backoff.next_delay())

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
        """Subscribed to what is followed, publishing until cancelled or the connection is
        lost; the box's own events forwarded while it doesn't serve its lines."""
        self._backoff.reset()
        tasks: dict[str, asyncio.Task[None]] = {}
        topics = list(dict.fromkeys(topic for each in self.followed for topic in each.topics))
        try:
            if topics:
                await client.subscribe([(topic, 1) for topic in topics])
                tasks["told"] = self._task(self._follow(client), "redundancy:told")
            await self._publish_until_cancelled(client, tasks)
        finally:
            for task in tasks.values():
                await _ended(task)

    def _task(self, work: Coroutine[Any, Any, None], name: str) -> asyncio.Task[None]:
        task = asyncio.create_task(work, name=name)
        task.add_done_callback(lambda _: self._changed.set())  # the loop sees its end at once
        return task

    async def _follow(self, client: aiomqtt.Client) -> None:
        async for message in client.messages:
            payload = message.payload
            if isinstance(payload, bytes | bytearray):
                for follower in self.followed:
                    follower.take(str(message.topic), bytes(payload))

    async def _forward(self, client: aiomqtt.Client) -> None:
        assert self._events is not None
        topic = Topics(self.mqtt.base_topic).bridge_event

        async def publish(payload: str) -> None:
            await client.publish(topic, payload, qos=1)

        await forward_stored(self._events, publish, self.box)

    async def _publish_until_cancelled(
        self, client: aiomqtt.Client, tasks: dict[str, asyncio.Task[None]]
    ) -> None:
        config_sent: bytes | None = None
        try:
            while True:
                for task in tasks.values():
                    if task.done():
                        if not task.cancelled():
                            task.result()  # what ended it (a lost connection's MqttError)
                        raise aiomqtt.MqttError("the role connection was lost")
                self._changed.clear()
                await self._hand_events(client, tasks)
                if self._peer is not None:
                    config = dump({"box": self.box, "keys": self._peer.digests()})
                    if config != config_sent:
                        await client.publish(self._config_topic, config, qos=1, retain=True)
                        config_sent = config
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

    async def _hand_events(
        self, client: aiomqtt.Client, tasks: dict[str, asyncio.Task[None]]
    ) -> None:
        """This box's events go out here while it doesn't serve its lines, and stop before the
        bridge's forwarding takes the store (`EventStore.forwarding`)."""
        if self._events is None:
            return
        forwarding = tasks.get("events")
        if self._forwards() and forwarding is None:
            tasks["events"] = self._task(self._forward(client), "redundancy:events")
        elif not self._forwards() and forwarding is not None:
            del tasks["events"]
            await _ended(forwarding)

    @property
    def _config_topic(self) -> str:
        return f"{self.topic}/{CONFIG_LEVEL}"


async def _ended(task: asyncio.Task[None]) -> None:
    """`task` cancelled unless it ended (the connection lost: its MqttError is the loop's)."""
    if not task.done():
        await cancel_and_wait(task, BYE_S)
    elif not task.cancelled():
        task.exception()  # retrieved: the loop has raised it, or another's end came first


def _digest(keys: Mapping[str, str]) -> str:
    """One digest of the shared configuration's: the same on two boxes that run it alike."""
    return hashlib.sha256(dump(dict(keys))).hexdigest()[:12]
