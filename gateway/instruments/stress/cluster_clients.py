"""The plant's side of `stress --cluster`: a dashboard with a persistent QoS 1 session, an
operator sending set-points, and a fresh reader of retained states, each on a node of the
cluster.

The dashboard is moved off a node (a clean DISCONNECT, then the same client id on a live node:
the session and what it missed are kept in the cluster's JetStream) just before that node is
killed, so that it sees the gateways come back when they do, not when it finds its own way back.
The operator publishes at QoS 1 through whichever node is alive, as the plant's software would.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import time
import uuid
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import aiomqtt

from gateway.instruments.nats_cluster import NatsNode

log = logging.getLogger(__name__)

RETRY_S = 0.2
CLIENT_TIMEOUT_S = 5.0
READ_WINDOW_S = 1.5
"""How long a retained read waits for every drive's state before it counts what came."""


@dataclass(frozen=True, slots=True)
class Received:
    at: float
    """monotonic() when the dashboard got it."""
    topic: str
    data: Any
    retained: bool
    """Sent as the broker's retained copy (at a subscription), not as it was published."""


def _json(payload: object) -> Any:
    try:
        return json.loads(payload if isinstance(payload, bytes | str) else b"")
    except ValueError:
        return None


def quiet_lost_connections(loop: asyncio.AbstractEventLoop) -> None:
    """aiomqtt keeps a lost connection's error in a future that nothing reads once its client is
    left, and asyncio prints "Future exception was never retrieved" for each: here every loss is
    expected (nodes are killed) and handled (the client connects again), so those are dropped.
    Anything else goes to the handler there was."""
    previous = loop.get_exception_handler()

    def handler(loop: asyncio.AbstractEventLoop, context: dict[str, Any]) -> None:
        lost = isinstance(context.get("exception"), aiomqtt.MqttError)
        if lost and "never retrieved" in str(context.get("message", "")):
            return
        if previous is None:
            loop.default_exception_handler(context)
        else:
            previous(loop, context)

    loop.set_exception_handler(handler)


def _live(nodes: Sequence[NatsNode], avoid: NatsNode | None) -> list[NatsNode]:
    return [node for node in nodes if node.running and node is not avoid]


class Dashboard:
    """Everything on `<site>/+/bridge/event` and `<site>/+/bridge/state`, in order."""

    def __init__(self, nodes: Sequence[NatsNode], site: str) -> None:
        self.nodes = nodes
        self.site = site
        self.identifier = f"stress-dashboard-{uuid.uuid4().hex[:8]}"
        self.messages: list[Received] = []
        self.node: NatsNode | None = None
        """The node it is connected to now."""
        self.connections = 0
        self._avoid: NatsNode | None = None
        self._leave = asyncio.Event()
        self._moved = asyncio.Event()
        """Set whenever `node` changes."""

    def event_ids(self, base: str) -> list[int]:
        """Every event id received from one gateway, duplicates included."""
        topic = f"{base}/bridge/event"
        return [
            int(m.data["id"])
            for m in self.messages
            if m.topic == topic and isinstance(m.data, dict) and isinstance(m.data.get("id"), int)
        ]

    def online_after(self, base: str, moment: float, not_via: str | None = None) -> Received | None:
        """The gateway's first "online" received after `moment`, not naming node `not_via`
        (the retained copy a subscription brings again names the node it was on then: the
        retain flag can't tell it, as NATS may keep it on a queued message)."""
        topic = f"{base}/bridge/state"
        for message in self.messages:
            if (
                message.at > moment
                and message.topic == topic
                and isinstance(message.data, dict)
                and message.data.get("state") == "online"
                and (not_via is None or message.data.get("server") != not_via)
            ):
                return message
        return None

    def server_of(self, base: str) -> str | None:
        """The node a gateway said last it is connected to (its `bridge/state`'s `server`)."""
        topic = f"{base}/bridge/state"
        for message in reversed(self.messages):
            if message.topic == topic and isinstance(message.data, dict):
                server = message.data.get("server")
                return server if message.data.get("state") == "online" else None
        return None

    async def move_off(self, node: NatsNode) -> None:
        """Onto another node before `node` dies; returns once connected there."""
        self._avoid = node
        if self.node is node:
            self._leave.set()
        while self.node is None or self.node is node:
            self._moved.clear()
            await self._moved.wait()

    def _on(self, node: NatsNode | None) -> None:
        self.node = node
        self._moved.set()

    async def run(self) -> None:
        while True:
            live = _live(self.nodes, self._avoid) or _live(self.nodes, None)
            if not live:
                await asyncio.sleep(RETRY_S)
                continue
            node = live[0]
            try:
                await self._connected(node)
            except aiomqtt.MqttError as exc:
                log.info("dashboard on %s: %s", node.name, exc)
                self._on(None)
                await asyncio.sleep(RETRY_S)

    async def _connected(self, node: NatsNode) -> None:
        client = aiomqtt.Client(
            node.host,
            node.port,
            identifier=self.identifier,
            clean_session=False,
            timeout=CLIENT_TIMEOUT_S,
            keepalive=5,
        )
        try:
            await self._session(client, node)
        finally:
            self._on(None)

    async def _session(self, client: aiomqtt.Client, node: NatsNode) -> None:
        async with client:
            # Subscribed again at each connection: the session has them, and where it was lost
            # this is what brings them back.
            await client.subscribe(f"{self.site}/+/bridge/event", qos=1)
            await client.subscribe(f"{self.site}/+/bridge/state", qos=1)
            self.connections += 1
            self._leave.clear()
            self._on(node)
            if node is self._avoid:  # told to move off it while this connection was made
                self._leave.set()
            collect = asyncio.create_task(self._collect(client))
            leave = asyncio.create_task(self._leave.wait())
            try:
                await asyncio.wait({collect, leave}, return_when=asyncio.FIRST_COMPLETED)
            finally:
                for task in (collect, leave):
                    task.cancel()
                    with contextlib.suppress(asyncio.CancelledError):
                        await task
            if collect.done() and not collect.cancelled() and collect.exception() is not None:
                raise aiomqtt.MqttError(str(collect.exception()))

    async def _collect(self, client: aiomqtt.Client) -> None:
        async for message in client.messages:
            self.messages.append(
                Received(
                    time.monotonic(),
                    str(message.topic),
                    _json(message.payload),
                    bool(message.retain),
                )
            )


class StateWatch:
    """`<site>/+/bridge/state` at QoS 0 through every running node: when each gateway said
    "online", as early as any node can tell. A QoS 0 subscription is plain NATS, with no
    JetStream consumer behind it, so the cluster's elections after a node's death delay it not
    (the dashboard's QoS 1 session they may)."""

    def __init__(self, nodes: Sequence[NatsNode], site: str) -> None:
        self.nodes = nodes
        self.site = site
        self.online: list[tuple[float, str, str]] = []
        """(monotonic() when seen, topic, the node it names) of every live "online"."""

    def server_of(self, base: str) -> str | None:
        """The node the gateway's latest "online" named, if one was seen."""
        topic = f"{base}/bridge/state"
        return next((server for _, seen, server in reversed(self.online) if seen == topic), None)

    def online_after(self, base: str, moment: float) -> tuple[float, str] | None:
        """(when, through which node) of the gateway's first "online" after `moment`."""
        topic = f"{base}/bridge/state"
        return next(
            ((at, server) for at, seen, server in self.online if at > moment and seen == topic),
            None,
        )

    async def run(self) -> None:
        async with asyncio.TaskGroup() as tasks:
            for node in self.nodes:
                tasks.create_task(self._watch(node), name=f"stress:watch-{node.name}")

    async def _watch(self, node: NatsNode) -> None:
        while True:
            if node.running:
                client = aiomqtt.Client(
                    node.host,
                    node.port,
                    identifier=f"stress-watch-{uuid.uuid4().hex[:8]}",
                    timeout=2,
                    keepalive=5,
                )
                try:
                    async with client:
                        await client.subscribe(f"{self.site}/+/bridge/state", qos=0)
                        async for message in client.messages:
                            data = _json(message.payload)
                            online = isinstance(data, dict) and data.get("state") == "online"
                            if online and not message.retain:
                                server = str(data.get("server"))
                                self.online.append((time.monotonic(), str(message.topic), server))
                except aiomqtt.MqttError as exc:
                    log.info("watch on %s: %s", node.name, exc)
            await asyncio.sleep(RETRY_S)


@dataclass(frozen=True, slots=True)
class SetPoint:
    base: str
    drive: str
    frequency_hz: float


class Operator:
    """Set-points to the drives through a live node, each a frequency no other command has."""

    def __init__(self, nodes: Sequence[NatsNode]) -> None:
        self.nodes = nodes
        self.sent: list[SetPoint] = []
        """Acknowledged by the broker (QoS 1)."""
        self.failed = 0
        """Not acknowledged: the node died under it (it may or may not have gone on)."""
        self._client: aiomqtt.Client | None = None
        self._node: NatsNode | None = None

    async def send(self, set_point: SetPoint) -> None:
        topic = f"{set_point.base}/{set_point.drive}/set"
        payload = json.dumps({"frequency_hz": set_point.frequency_hz})
        try:
            client = await self._connect()
            await asyncio.wait_for(client.publish(topic, payload, qos=1), CLIENT_TIMEOUT_S)
        except (aiomqtt.MqttError, TimeoutError) as exc:
            log.info("operator: %s", exc)
            self.failed += 1
            await self.close()
            return
        self.sent.append(set_point)

    async def _connect(self) -> aiomqtt.Client:
        if self._client is not None and self._node is not None and self._node.running:
            return self._client
        await self.close()
        live = _live(self.nodes, None)
        if not live:
            raise aiomqtt.MqttError("no node is running")
        client = aiomqtt.Client(
            live[0].host,
            live[0].port,
            identifier=f"stress-operator-{uuid.uuid4().hex[:8]}",
            timeout=CLIENT_TIMEOUT_S,
        )
        await client.__aenter__()
        self._client, self._node = client, live[0]
        return client

    async def close(self) -> None:
        client, self._client, self._node = self._client, None, None
        if client is not None:
            with contextlib.suppress(Exception):
                await client.__aexit__(None, None, None)


async def read_retained(node: NatsNode, topics: set[str], site: str) -> dict[str, Any]:
    """The retained states as a dashboard connecting to `node` now reads them: topic → payload,
    for those of `topics` that came within `READ_WINDOW_S`. At QoS 0: a QoS 1 subscription is a
    replicated JetStream consumer, slow to make while a node is down (`gateway.mqtt.connection`)."""
    found: dict[str, Any] = {}
    client = aiomqtt.Client(
        node.host, node.port, identifier=f"stress-reader-{uuid.uuid4().hex[:8]}", timeout=2
    )
    try:
        async with client:
            await client.subscribe(f"{site}/+/+", qos=0)

            async def collect() -> None:
                async for message in client.messages:
                    topic = str(message.topic)
                    if message.retain and topic in topics:
                        found[topic] = _json(message.payload)
                        if len(found) == len(topics):
                            return

            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(collect(), READ_WINDOW_S)
    except aiomqtt.MqttError as exc:
        log.info("reader on %s: %s", node.name, exc)
    return found


async def wait_carrying_retained(
    nodes: Sequence[NatsNode], site: str, timeout_s: float
) -> float | None:
    """Until a retained message published through each of `nodes` is read through every other
    one: the cluster carries retained messages between its nodes again. Seconds waited; None
    when that did not come within `timeout_s` (NATS 2.9.10 was seen to leave a node's consumer
    "with NO quorum, stalled" for good after a few SIGKILLs, with every node up).

    After a node's death NATS 2.9 may not for several seconds: each node learns what was
    published through the others from its own consumer of the retained messages' stream, and a
    consumer whose leader was the dead node hears nothing until it has elected another (4-9 s,
    the raft election timeouts). Nothing a client does changes that; a retained read timed from
    a change made meanwhile would time NATS's election, not the gateways.
    """
    started = time.monotonic()
    token = uuid.uuid4().hex[:8]
    topics = {f"{site}/stress-probe/{node.name}": node for node in nodes}
    while True:
        for topic, node in topics.items():
            await _publish_retained(node, topic, token)
        seen = await asyncio.gather(*(read_retained(node, set(topics), site) for node in nodes))
        if all(all(found.get(t) == token for t in topics) for found in seen):
            return time.monotonic() - started
        if time.monotonic() - started > timeout_s:
            return None
        await asyncio.sleep(RETRY_S)


async def _publish_retained(node: NatsNode, topic: str, token: str) -> None:
    """At QoS 0: at QoS 1 NATS also stores it in a stream that may be electing its leader, and
    closes the connection when that times out (what `mqtt.publish_qos` is about)."""
    client = aiomqtt.Client(
        node.host, node.port, identifier=f"stress-probe-{uuid.uuid4().hex[:8]}", timeout=2
    )
    try:
        async with client:
            await client.publish(topic, json.dumps(token), qos=0, retain=True)
    except aiomqtt.MqttError as exc:
        log.info("probe on %s: %s", node.name, exc)
