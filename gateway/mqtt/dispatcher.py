"""Received messages to their command kinds, each run in its lane, every sender answered.

The receiving loop never waits for a drive: it stamps each message with the time it came and
looks its topic up in a table of command kinds (`gateway.mqtt.kinds`). The kind says which lane
the message waits in (or that it needs none), and runs it when its turn comes: commands to one
drive in the order they came, different drives in parallel, `/get` on a lane of its own. A lane
that is full answers `busy`; a kind that fails of a bug answers `internal_error`; neither ends
the session for every other message.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Awaitable, Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any, Protocol

import aiomqtt

from gateway.errors import CommandRefused, ExceptionCode
from gateway.mqtt.lanes import Lanes
from gateway.mqtt.requests import Json, error_response, parse_object
from gateway.mqtt.stats import BridgeStats

log = logging.getLogger(__name__)

BUSY_LOG_EVERY = 100
"""The first refusal for a full lane is logged as a warning, then one line per this many."""

Answer = Callable[[aiomqtt.Client, str, Json], Awaitable[None]]
"""Publishes a response on a topic; says nothing when the connection is gone."""
ClearRetained = Callable[[aiomqtt.Client, str], Awaitable[None]]
"""Removes the retained message on a topic (an empty retained publish), and says so."""
ClearAfterRun = Callable[[aiomqtt.Client, str], Awaitable[None]]
"""Removes whatever may be retained on a command's topic once the command ran, quietly."""


@dataclass(frozen=True, slots=True)
class Incoming:
    """One received message."""

    topic: str
    payload: bytes
    retained: bool
    received_at: float
    """Monotonic time the receive loop got it: the start of its `command_max_age_s`."""


class CommandKind(Protocol):
    """What one kind of message does; one instance per topic it is subscribed on."""

    @property
    def command(self) -> bool:
        """Sent by someone to have something done: never taken retained, never empty."""

    @property
    def response_topic(self) -> str | None:
        """Where its answers go (a `busy` or `internal_error` too), or None: no answer."""

    def lane(self, message: Incoming) -> str | None:
        """The lane it waits in; None when it needs nothing run (handled or ignored at once)."""

    async def run(self, client: aiomqtt.Client, message: Incoming) -> None:
        """Its turn has come: do it, and answer."""


class OtherTopics(Protocol):
    """A wildcard subscription over some of the kinds' topics, with a kind for the topics it
    brings that no kind has (`kinds.AnySet`: a `/set` of a drive this gateway hasn't)."""

    @property
    def filter(self) -> str: ...

    def covers(self, topic: str) -> bool: ...

    def kind(self, topic: str) -> CommandKind | None: ...


class Dispatcher:
    def __init__(
        self,
        kinds: Mapping[str, CommandKind],
        lanes: Lanes,
        answer: Answer,
        stats: BridgeStats,
        clear_retained: ClearRetained | None = None,
        clear_after_run: Callable[[], ClearAfterRun | None] | None = None,
        others: OtherTopics | None = None,
    ) -> None:
        """`clear_after_run`: asked after each command ran; what clears its topic then (the
        bridge's under MQTT 3.1.1), or None: nothing to clear."""
        self.kinds = kinds
        self.lanes = lanes
        self.answer = answer
        self.stats = stats
        self.clear_retained = clear_retained
        self.clear_after_run = clear_after_run
        self.others = others

    @property
    def topics(self) -> Iterable[str]:
        """What to subscribe to: the kinds' topics, those a wildcard covers by it alone (two
        overlapping subscriptions may bring a message twice)."""
        others = self.others
        if others is None:
            return self.kinds.keys()
        return [*(t for t in self.kinds if not others.covers(t)), others.filter]

    async def run(self, client: aiomqtt.Client) -> None:
        """Receive for as long as the connection lasts."""
        async for message in client.messages:
            incoming = Incoming(
                str(message.topic),
                _payload(message.payload),
                bool(message.retain),
                time.monotonic(),
            )
            try:
                self.dispatch(client, incoming)
            except Exception:
                # A bug (or a payload nested deep enough to exhaust the parser's recursion)
                # must not end the session for every other message.
                log.exception("MQTT: a message on %s could not be dispatched", incoming.topic)

    def dispatch(self, client: aiomqtt.Client, incoming: Incoming) -> None:
        """Hand the message to its lane; nothing here waits (for a drive or the broker)."""
        kind = self.kinds.get(incoming.topic)
        if kind is None and self.others is not None:
            kind = self.others.kind(incoming.topic)
        if kind is None:
            self.stats.ignored += 1
            return
        if kind.command and not incoming.payload.strip():
            # An empty payload is how a retained message is cleared (ours, or someone's):
            # nothing to do, nothing to answer.
            self.stats.ignored += 1
            return
        if kind.command and incoming.retained and self.clear_retained is not None:
            # Refused by the kind as `retained`; cleared here, or it runs again for the next
            # subscriber (another gateway, this one after a restart).
            self._clear(client, incoming.topic)
        lane = kind.lane(incoming)
        if lane is None:
            return

        async def job() -> None:
            await self._run(client, kind, incoming)
            if kind.command:
                await self._clear_after_run(client, incoming.topic)

        if not self.lanes.submit(lane, job):
            self._refuse_busy(client, lane, incoming, kind.response_topic)

    async def _run(self, client: aiomqtt.Client, kind: CommandKind, incoming: Incoming) -> None:
        try:
            await kind.run(client, incoming)
        except aiomqtt.MqttError as exc:
            # The connection is gone (the session ends with it): nobody is left to answer.
            log.debug("MQTT: no answer to %s: %s", incoming.topic, exc)
        except Exception:
            # A bug in one kind must not take the bridge down; the sender gets an answer.
            log.exception("MQTT: handling a message on %s failed", incoming.topic)
            if kind.response_topic is not None:
                response = error_response(
                    transaction(incoming.payload),
                    "internal_error",
                    "the gateway failed; see its log",
                )
                await self.answer(client, kind.response_topic, response)

    async def _clear_after_run(self, client: aiomqtt.Client, topic: str) -> None:
        """Under MQTT 3.1.1 a broker delivers a message retained while we are subscribed
        without its retain flag: a retained command then looks fresh and runs (as documented),
        and stayed retained on the broker for the next subscriber (another gateway, this one
        after a restart, which would refuse it, but a dashboard shows it). Nothing tells it
        from a fresh one, so every command's topic is cleared once it ran: an empty retained
        publish, which costs nothing where nothing is retained."""
        clear = self.clear_after_run() if self.clear_after_run is not None else None
        if clear is None:
            return
        try:
            await clear(client, topic)
        except aiomqtt.MqttError as exc:
            log.debug("MQTT: %s not cleared after its command: %s", topic, exc)

    def _clear(self, client: aiomqtt.Client, topic: str) -> None:
        clear = self.clear_retained
        assert clear is not None

        async def job() -> None:
            await clear(client, topic)

        self.lanes.submit("retained", job)

    def _refuse_busy(
        self, client: aiomqtt.Client, lane: str, incoming: Incoming, response_topic: str | None
    ) -> None:
        self.stats.busy += 1
        max_waiting = self.lanes.max_waiting
        if self.stats.busy % BUSY_LOG_EVERY == 1:
            log.warning(
                "MQTT: %d messages already wait in lane %s; refused as busy (%d so far)",
                max_waiting,
                lane,
                self.stats.busy,
            )
        if response_topic is None:
            return
        response: Json = error_response(
            transaction(incoming.payload),
            "busy",
            f"{max_waiting} earlier requests are waiting: try again later",
            ExceptionCode.GATEWAY_PATH_UNAVAILABLE,
        )

        async def answer() -> None:
            await self.answer(client, response_topic, response)

        # Answered off the receive loop too; if even that lane is full, the flood gets silence.
        self.lanes.submit("busy", answer)


def transaction(payload: bytes) -> Any:
    """The `transaction` a payload carries, to echo in its answer (None if it has none)."""
    try:
        return parse_object(payload).get("transaction")
    except CommandRefused:
        return None


def _payload(payload: Any) -> bytes:
    if isinstance(payload, bytes | bytearray):
        return bytes(payload)
    if payload is None:
        return b""
    return str(payload).encode()
