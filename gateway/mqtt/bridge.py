"""The MQTT bridge: telemetry out to the broker, commands in to the drives.

    start    one named task runs the connection loop; start() returns at once (a broker that is
             down must never delay the gateway: Modbus-TCP serves without it)
    tls      the TLS context is built once, before the first attempt; a bad file is logged once,
             naming its key, and tried again with backoff (the loop never ends over it)
    connect  publish online, info, discovery, every availability and retained state; subscribe
    session  a publishing task (from the poller's outbox) and the receiving loop, in one TaskGroup
    lost     any error ends the session; wait (jittered, capped backoff) and connect again
    stop     publish offline, cancel what is being handled, disconnect

The poller never waits for the bridge: it hands states and events to the bounded `Outbox` and
returns. A drive's state is published when it changed (`last_seen` aside) or every
`publish_interval_s`, retained, so a dashboard that subscribes late still gets it at once. What a
broken connection kept from being published goes back to the outbox, to go out after the next
connect.

The receiving loop never waits for a drive: it stamps each message with the time it came and
hands it to its lane (`Lanes`): commands to one drive run in the order they came, different
drives in parallel, `/get` on a lane of its own. A command whose turn comes later than
`command_max_age_s` after it came is answered `stale` instead of being run; a lane that is full
answers `busy`. When a connection is lost, what had not started yet is dropped with it.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import ssl
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any

import aiomqtt

from gateway import __version__
from gateway.config import GatewayConfig, MqttConfig
from gateway.errors import CommandRefused, ExceptionCode, TlsSettingsError
from gateway.mqtt.commands import CommandHandler
from gateway.mqtt.connection import (
    OFFLINE,
    ONLINE,
    Backoff,
    client_id,
    make_client,
    tls_context,
)
from gateway.mqtt.discovery import discovery_messages
from gateway.mqtt.lanes import Lanes
from gateway.mqtt.outbox import Outbox, Pending
from gateway.mqtt.requests import Json, error_response, parse_object
from gateway.mqtt.topics import BRIDGE_REQUESTS, Topics
from gateway.poller import DriveEvent, Poller
from gateway.poller.drive_state import iso_time
from gateway.profile.telemetry import Telemetry
from gateway.router import Router
from gateway.tasks import cancel_and_wait

log = logging.getLogger(__name__)

QOS = 1
RECONNECT_INITIAL_S = 0.5
PUBLISH_TICK_S = 1.0
"""How often the publisher looks again when nothing new came (the periodic republish)."""
STOP_PUBLISH_TIMEOUT_S = 0.3
STOP_TASK_BUDGET_S = 0.6
"""With the offline message, inside the 1 s the application gives each feature to stop."""
MAX_WAITING_PER_LANE = 16
"""Messages for one drive waiting for their turn; past this they are answered `busy`."""
BUSY_LOG_EVERY = 100
"""The first refusal for a full lane is logged as a warning, then one line per this many."""


@dataclass(slots=True)
class BridgeStats:
    connects: int = 0
    connect_failures: int = 0
    published: int = 0
    commands_received: int = 0
    ignored: int = 0
    conflicts: int = 0
    busy: int = 0
    """Messages refused because their lane was full."""
    tls_failures: int = 0
    """Attempts to build the TLS context from the configured files that failed."""


@dataclass(frozen=True, slots=True)
class Incoming:
    """One received message."""

    topic: str
    payload: bytes
    retained: bool
    received_at: float
    """Monotonic time the receive loop got it: the start of its `command_max_age_s`."""


Handler = Callable[[aiomqtt.Client, Incoming], Awaitable[None]]


class MqttBridge:
    def __init__(self, config: GatewayConfig, router: Router, poller: Poller) -> None:
        assert config.mqtt is not None
        self.config = config
        self.mqtt: MqttConfig = config.mqtt
        self.poller = poller
        self.topics = Topics(self.mqtt.base_topic)
        self.outbox = Outbox(self.mqtt.queue_size)
        self.commands = CommandHandler(
            self.mqtt, router, poller, {d.name: d.model for d in config.drives}
        )
        self.stats = BridgeStats()
        self.connected = asyncio.Event()
        self._client: aiomqtt.Client | None = None
        self._task: asyncio.Task[None] | None = None
        self._published: dict[str, tuple[str, float]] = {}
        """Drive → (its last state payload without last_seen, monotonic time published)."""
        self._availability: dict[str, bool] = {}
        """Drive → the availability last published on this connection."""
        self._drives = frozenset(d.name for d in config.drives)
        self._set_topics = {self.topics.set(d.name): d.name for d in config.drives}
        self._get_topics = {self.topics.get(d.name): d.name for d in config.drives}
        self._bridge_operations = {self.topics.bridge_request(op): op for op in BRIDGE_REQUESTS}
        self._ha_status = f"{self.mqtt.discovery_prefix}/status"
        self._other_gateways: set[str] = set()
        self._lanes = Lanes(MAX_WAITING_PER_LANE)

    # -- PollListener: called by the poller, return at once ----------------------------------

    def state_updated(self, drive: str, telemetry: Telemetry) -> None:
        self.outbox.put_state(drive, telemetry)

    def availability_changed(self, drive: str, online: bool) -> None:
        self.outbox.put_availability(drive, online)

    def drive_event(self, event: DriveEvent) -> None:
        self.outbox.put_event(event)

    # -- lifecycle ---------------------------------------------------------------------------

    async def start(self) -> None:
        self._task = asyncio.create_task(self._run(), name="mqtt:bridge")

    async def stop(self) -> None:
        client = self._client
        if client is not None:  # connected, maybe still setting up: online may be out
            # A clean disconnect sends no last will: say "offline" ourselves.
            with contextlib.suppress(aiomqtt.MqttError):
                await client.publish(
                    self.topics.bridge_state,
                    OFFLINE,
                    qos=QOS,
                    retain=True,
                    timeout=STOP_PUBLISH_TIMEOUT_S,
                )
        # Commands being carried out are cut off: the buses are closed by now anyway.
        stopping: list[Awaitable[object]] = [self._lanes.close(STOP_TASK_BUDGET_S)]
        if self._task is not None:
            stopping.append(cancel_and_wait(self._task, STOP_TASK_BUDGET_S))
        await asyncio.gather(*stopping)
        self._task = None

    async def _run(self) -> None:
        backoff = Backoff(RECONNECT_INITIAL_S, self.mqtt.reconnect_max_s)
        tls = await self._tls_context(backoff)
        failures = 0
        while True:
            try:
                # Inside the try: whatever building a client raises is one more failed attempt,
                # never the end of the loop.
                client = make_client(self.config, self.topics, tls)
                async with client:
                    self._client = client
                    if failures:
                        log.info("MQTT: connected again after %d failed attempts", failures)
                    failures = 0
                    backoff.reset()
                    await self._session(client)
            except* aiomqtt.MqttError as group:
                failures += 1
                self.stats.connect_failures += 1
                self._log_failure(failures, group.exceptions[0])
            except* Exception:
                # A bug, or a client that can't be built: not the broker, but the bridge must not
                # die of it either. The whole story once, then a line per attempt.
                failures += 1
                self.stats.connect_failures += 1
                if failures == 1:
                    log.exception("MQTT bridge failed; retrying with backoff")
                else:
                    log.debug("MQTT bridge failed again (attempt %d)", failures, exc_info=True)
            finally:
                self._client = None
                self.connected.clear()
                # A command that came on a lost connection never runs after the next one is up.
                self._lanes.drop_waiting()
            await asyncio.sleep(backoff.next_delay())

    async def _tls_context(self, backoff: Backoff) -> ssl.SSLContext | None:
        """Built once for every attempt; until the files are usable, tried again with backoff."""
        while True:
            try:
                tls = tls_context(self.mqtt)
            except TlsSettingsError as exc:
                self.stats.tls_failures += 1
                if self.stats.tls_failures == 1:
                    log.error(
                        "MQTT: %s; no connection to the broker until it is fixed "
                        "(checking again with backoff)",
                        exc,
                    )
                else:
                    log.debug("MQTT: %s (attempt %d)", exc, self.stats.tls_failures)
                await asyncio.sleep(backoff.next_delay())
                continue
            if self.stats.tls_failures:
                log.info("MQTT: the TLS files are usable now")
                backoff.reset()
            return tls

    def _log_failure(self, failures: int, exc: BaseException) -> None:
        where = f"{self.mqtt.host}:{self.mqtt.port}"
        # Loudly once, then quietly: a broker down for a night must not flood the journal.
        level = logging.WARNING if failures == 1 else logging.DEBUG
        log.log(
            level,
            "MQTT broker %s: %s; reconnecting with backoff (attempt %d)",
            where,
            exc,
            failures,
        )

    # -- one connection ----------------------------------------------------------------------

    async def _session(self, client: aiomqtt.Client) -> None:
        self.stats.connects += 1
        log.info(
            "MQTT: connected to %s:%d as %s", self.mqtt.host, self.mqtt.port, client_id(self.config)
        )
        await self._publish(client, self.topics.bridge_state, ONLINE, retain=True)
        await self._publish(client, self.topics.bridge_info, self._info(), retain=True)
        await self._subscribe(client)
        if self.mqtt.homeassistant_discovery:
            await self._publish_discovery(client)
        await self._republish(client)
        self.connected.set()
        async with asyncio.TaskGroup() as tasks:
            tasks.create_task(self._publish_forever(client), name="mqtt:publish")
            tasks.create_task(self._receive_forever(client), name="mqtt:receive")

    async def _subscribe(self, client: aiomqtt.Client) -> None:
        topics = [*self._set_topics, *self._get_topics, self.topics.bridge_info]
        topics += [self.topics.bridge_request(op) for op in BRIDGE_REQUESTS]
        if self.mqtt.homeassistant_discovery:
            topics.append(self._ha_status)
        await client.subscribe([(topic, QOS) for topic in topics])

    async def _republish(self, client: aiomqtt.Client) -> None:
        """After (re)connecting: every drive's availability and last state, as the poller has it."""
        self._published.clear()
        self._availability.clear()
        for drive in self.poller.drives:
            online = self.poller.availability(drive)
            if online is not None:
                await self._publish_availability(client, drive, online)
            telemetry = self.poller.telemetry(drive)
            if "last_seen" in telemetry:
                await self._publish_state(client, drive, telemetry, force=True)

    async def _publish_discovery(self, client: aiomqtt.Client) -> None:
        messages = discovery_messages(self.config, self.mqtt.discovery_prefix, self.topics)
        for topic, payload in messages:
            await self._publish(client, topic, payload, retain=True)
        log.info("MQTT: Home Assistant discovery published (%d entities)", len(messages))

    # -- out -----------------------------------------------------------------------------------

    async def _publish_forever(self, client: aiomqtt.Client) -> None:
        while True:
            await self.outbox.wait(PUBLISH_TICK_S)
            pending = self.outbox.take()
            try:
                await self._publish_pending(client, pending)
            finally:
                # An error or the session's end (a cancellation) halfway: what is left was not
                # sent; it goes back, in front, for the next connection.
                if pending:
                    self.outbox.restore(pending)

    async def _publish_pending(self, client: aiomqtt.Client, pending: Pending) -> None:
        """Publish and remove each item in turn: what is left in `pending` was not sent."""
        while pending.availability:
            drive, online = next(iter(pending.availability.items()))
            await self._publish_availability(client, drive, online)
            del pending.availability[drive]
        while pending.events:
            await self._publish_event(client, pending.events[0])
            pending.events.popleft()
        while pending.states:
            drive, telemetry = next(iter(pending.states.items()))
            await self._publish_state(client, drive, telemetry)
            del pending.states[drive]

    async def _publish_state(
        self, client: aiomqtt.Client, drive: str, telemetry: Telemetry, force: bool = False
    ) -> None:
        compared = json.dumps({k: v for k, v in telemetry.items() if k != "last_seen"})
        last = self._published.get(drive)
        now = time.monotonic()
        if not force and last is not None:
            unchanged = last[0] == compared
            if unchanged and now - last[1] < self.mqtt.publish_interval_s:
                return
        await self._publish(client, self.topics.drive_state(drive), _dump(telemetry), retain=True)
        self._published[drive] = (compared, now)

    async def _publish_availability(self, client: aiomqtt.Client, drive: str, online: bool) -> None:
        if self._availability.get(drive) is online:
            return  # already said, on this connection
        payload = ONLINE if online else OFFLINE
        await self._publish(client, self.topics.availability(drive), payload, retain=True)
        self._availability[drive] = online

    async def _publish_event(self, client: aiomqtt.Client, event: DriveEvent) -> None:
        data = {"drive": event.drive, **event.data, "time": iso_time(event.at)}
        payload = _dump({"type": str(event.kind), "data": data})
        await self._publish(client, self.topics.bridge_event, payload)

    async def _publish(
        self, client: aiomqtt.Client, topic: str, payload: str, retain: bool = False
    ) -> None:
        await client.publish(topic, payload, qos=QOS, retain=retain)
        self.stats.published += 1

    def _info(self) -> str:
        return _dump(
            {
                "gateway_id": self.config.gateway_id,
                "version": __version__,
                "commands_enabled": self.mqtt.commands_enabled,
                "drives": [
                    {
                        "name": d.name,
                        "model": d.model,
                        "bus": d.bus,
                        "address": d.address,
                        "unit_id": d.effective_unit_id,
                    }
                    for d in self.config.drives
                ],
            }
        )

    # -- in ------------------------------------------------------------------------------------

    async def _receive_forever(self, client: aiomqtt.Client) -> None:
        async for message in client.messages:
            incoming = Incoming(
                str(message.topic),
                _payload(message.payload),
                bool(message.retain),
                time.monotonic(),
            )
            try:
                self._dispatch(client, incoming)
            except Exception:
                # A bug (or a payload nested deep enough to exhaust the parser's recursion)
                # must not end the session for every other message.
                log.exception("MQTT: a message on %s could not be dispatched", incoming.topic)

    def _dispatch(self, client: aiomqtt.Client, incoming: Incoming) -> None:
        """Hand the message to its lane; nothing here waits (for a drive or the broker)."""
        topic = incoming.topic
        if topic in self._set_topics:
            drive = self._set_topics[topic]
            self.stats.commands_received += 1
            handler = self._handler_set(drive)
            self._submit(
                client, f"drive:{drive}", incoming, handler, self.topics.set_response(drive)
            )
        elif topic in self._get_topics:
            drive = self._get_topics[topic]
            lane = f"get:{drive}"
            if self._lanes.waiting(lane):
                self.stats.ignored += 1  # the refresh already waiting publishes the same state
                return
            self._submit(client, lane, incoming, self._handler_get(drive), None)
        elif (operation := self._bridge_operations.get(topic)) is not None:
            if operation == "write_parameter":
                self.stats.commands_received += 1
            lane = self._bridge_lane(incoming.payload)
            handler = self._handler_bridge(operation)
            self._submit(client, lane, incoming, handler, self.topics.bridge_response(operation))
        elif topic == self._ha_status:
            if incoming.payload.strip() == b"online" and not self._lanes.waiting("discovery"):
                self._submit(client, "discovery", incoming, self._handle_discovery, None)
        elif topic == self.topics.bridge_info:
            self._check_alone(incoming.payload)
        else:
            self.stats.ignored += 1

    def _bridge_lane(self, payload: bytes) -> str:
        """A bridge request about a drive queues with that drive's commands, in order."""
        try:
            drive = parse_object(payload).get("drive")
        except CommandRefused:
            return "bridge"  # answered at once: invalid_request
        return f"drive:{drive}" if drive in self._drives else "bridge"

    def _submit(
        self,
        client: aiomqtt.Client,
        lane: str,
        incoming: Incoming,
        handler: Handler,
        response_topic: str | None,
    ) -> None:
        async def job() -> None:
            await self._handle(client, incoming, handler, response_topic)

        if not self._lanes.submit(lane, job):
            self._refuse_busy(client, lane, incoming, response_topic)

    async def _handle(
        self,
        client: aiomqtt.Client,
        incoming: Incoming,
        handler: Handler,
        response_topic: str | None,
    ) -> None:
        try:
            await handler(client, incoming)
        except aiomqtt.MqttError as exc:
            # The connection is gone (the session ends with it): nobody is left to answer.
            log.debug("MQTT: no answer to %s: %s", incoming.topic, exc)
        except Exception:
            # A bug in one handler must not take the bridge down; the sender gets an answer.
            log.exception("MQTT: handling a message on %s failed", incoming.topic)
            if response_topic is not None:
                response = error_response(
                    _transaction(incoming.payload),
                    "internal_error",
                    "the gateway failed; see its log",
                )
                await self._answer(client, response_topic, response)

    def _refuse_busy(
        self, client: aiomqtt.Client, lane: str, incoming: Incoming, response_topic: str | None
    ) -> None:
        self.stats.busy += 1
        if self.stats.busy % BUSY_LOG_EVERY == 1:
            log.warning(
                "MQTT: %d messages already wait in lane %s; refused as busy (%d so far)",
                MAX_WAITING_PER_LANE,
                lane,
                self.stats.busy,
            )
        if response_topic is None:
            return
        response = error_response(
            _transaction(incoming.payload),
            "busy",
            f"{MAX_WAITING_PER_LANE} earlier requests are waiting: try again later",
            ExceptionCode.GATEWAY_PATH_UNAVAILABLE,
        )

        async def answer() -> None:
            await self._answer(client, response_topic, response)

        # Answered off the receive loop too; if even that lane is full, the flood gets silence.
        self._lanes.submit("busy", answer)

    async def _answer(self, client: aiomqtt.Client, topic: str, response: Json) -> None:
        with contextlib.suppress(aiomqtt.MqttError):  # the connection is gone: nobody to tell
            await self._publish(client, topic, _dump(response))

    # -- what each kind of message does (run in its lane) --------------------------------------

    def _handler_set(self, drive: str) -> Handler:
        async def handle(client: aiomqtt.Client, incoming: Incoming) -> None:
            response = await self.commands.drive_set(
                drive, incoming.payload, incoming.retained, incoming.received_at
            )
            await self._publish(client, self.topics.set_response(drive), _dump(response))

        return handle

    def _handler_get(self, drive: str) -> Handler:
        async def handle(client: aiomqtt.Client, incoming: Incoming) -> None:
            if await self.commands.drive_get(
                drive, incoming.payload, incoming.retained, incoming.received_at
            ):
                telemetry = self.poller.telemetry(drive)
                await self._publish_state(client, drive, telemetry, force=True)

        return handle

    def _handler_bridge(self, operation: str) -> Handler:
        request = (
            self.commands.read_parameter
            if operation == "read_parameter"
            else self.commands.write_parameter
        )

        async def handle(client: aiomqtt.Client, incoming: Incoming) -> None:
            response = await request(incoming.payload, incoming.retained, incoming.received_at)
            await self._publish(client, self.topics.bridge_response(operation), _dump(response))

        return handle

    async def _handle_discovery(self, client: aiomqtt.Client, incoming: Incoming) -> None:
        await self._publish_discovery(client)

    def _check_alone(self, payload: bytes) -> None:
        """Another gateway publishing under our base topic would overwrite our retained state."""
        try:
            other = json.loads(payload).get("gateway_id")
        except (ValueError, AttributeError):
            return
        if isinstance(other, str) and other != self.config.gateway_id:
            self.stats.conflicts += 1
            if other not in self._other_gateways:
                self._other_gateways.add(other)
                log.error(
                    "MQTT: gateway %r also publishes under %r: give each gateway its own "
                    "base_topic",
                    other,
                    self.mqtt.base_topic,
                )


def _transaction(payload: bytes) -> Any:
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


def _dump(payload: dict[str, Any]) -> str:
    return json.dumps(payload, separators=(",", ":"))
