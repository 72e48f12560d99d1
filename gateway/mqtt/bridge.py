"""The MQTT bridge: telemetry out to the broker, commands in to the drives.

    start    one named task runs the connection loop; start() returns at once (a broker that is
             down must never delay the gateway: Modbus-TCP serves without it)
    connect  publish online, info, discovery, every availability and retained state; subscribe
    session  a publishing task (from the poller's outbox) and the receiving loop, in one TaskGroup
    lost     any MqttError ends the session; wait (jittered, capped backoff) and connect again
    stop     publish offline, disconnect

The poller never waits for the bridge: it hands states and events to the bounded `Outbox` and
returns. A drive's state is published when it changed (`last_seen` aside) or every
`publish_interval_s`, retained, so a dashboard that subscribes late still gets it at once.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import time
from dataclasses import dataclass
from typing import Any

import aiomqtt

from gateway import __version__
from gateway.config import GatewayConfig, MqttConfig
from gateway.mqtt.commands import CommandHandler
from gateway.mqtt.connection import OFFLINE, ONLINE, Backoff, client_id, make_client
from gateway.mqtt.discovery import discovery_messages
from gateway.mqtt.outbox import Outbox, Pending
from gateway.mqtt.requests import error_response
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


@dataclass(slots=True)
class BridgeStats:
    connects: int = 0
    connect_failures: int = 0
    published: int = 0
    commands_received: int = 0
    ignored: int = 0
    conflicts: int = 0


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
        self._set_topics = {self.topics.set(d.name): d.name for d in config.drives}
        self._get_topics = {self.topics.get(d.name): d.name for d in config.drives}
        self._ha_status = f"{self.mqtt.discovery_prefix}/status"
        self._other_gateways: set[str] = set()

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
        if self._task is not None:
            await cancel_and_wait(self._task, STOP_TASK_BUDGET_S)
            self._task = None

    async def _run(self) -> None:
        backoff = Backoff(RECONNECT_INITIAL_S, self.mqtt.reconnect_max_s)
        failures = 0
        while True:
            client = make_client(self.config, self.topics)
            try:
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
                # A bug or a bad setting (a TLS file), not the broker: the bridge must not die of
                # it. The whole story once, then a line per attempt.
                failures += 1
                if failures == 1:
                    log.exception("MQTT bridge failed; retrying with backoff")
                else:
                    log.debug("MQTT bridge failed again (attempt %d)", failures)
            finally:
                self._client = None
                self.connected.clear()
            await asyncio.sleep(backoff.next_delay())

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
            await self._publish_pending(client, self.outbox.take())

    async def _publish_pending(self, client: aiomqtt.Client, pending: Pending) -> None:
        for drive, online in pending.availability.items():
            await self._publish_availability(client, drive, online)
        for event in pending.events:
            await self._publish_event(client, event)
        for drive, telemetry in pending.states.items():
            await self._publish_state(client, drive, telemetry)

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
            topic = str(message.topic)
            payload = _payload(message.payload)
            try:
                await self._dispatch(client, topic, payload, bool(message.retain))
            except aiomqtt.MqttError:
                raise
            except Exception:
                # A bug in one handler must not take the bridge down; the sender gets an answer.
                log.exception("MQTT: handling a message on %s failed", topic)
                await self._answer_internal_error(client, topic, payload)

    async def _dispatch(
        self, client: aiomqtt.Client, topic: str, payload: bytes, retained: bool
    ) -> None:
        if topic in self._set_topics:
            drive = self._set_topics[topic]
            self.stats.commands_received += 1
            response = await self.commands.drive_set(drive, payload, retained)
            await self._publish(client, self.topics.set_response(drive), _dump(response))
        elif topic in self._get_topics:
            drive = self._get_topics[topic]
            if await self.commands.drive_get(drive, payload, retained):
                telemetry = self.poller.telemetry(drive)
                await self._publish_state(client, drive, telemetry, force=True)
        elif topic == self.topics.bridge_request("read_parameter"):
            response = await self.commands.read_parameter(payload, retained)
            await self._publish(
                client, self.topics.bridge_response("read_parameter"), _dump(response)
            )
        elif topic == self.topics.bridge_request("write_parameter"):
            self.stats.commands_received += 1
            response = await self.commands.write_parameter(payload, retained)
            await self._publish(
                client, self.topics.bridge_response("write_parameter"), _dump(response)
            )
        elif topic == self._ha_status:
            if payload.strip() == b"online":
                await self._publish_discovery(client)
        elif topic == self.topics.bridge_info:
            self._check_alone(payload)
        else:
            self.stats.ignored += 1

    async def _answer_internal_error(
        self, client: aiomqtt.Client, topic: str, payload: bytes
    ) -> None:
        response_topic = None
        if topic in self._set_topics:
            response_topic = self.topics.set_response(self._set_topics[topic])
        for operation in BRIDGE_REQUESTS:
            if topic == self.topics.bridge_request(operation):
                response_topic = self.topics.bridge_response(operation)
        if response_topic is not None:
            response = error_response(None, "internal_error", "the gateway failed; see its log")
            await self._publish(client, response_topic, _dump(response))

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


def _payload(payload: Any) -> bytes:
    if isinstance(payload, bytes | bytearray):
        return bytes(payload)
    if payload is None:
        return b""
    return str(payload).encode()


def _dump(payload: dict[str, Any]) -> str:
    return json.dumps(payload, separators=(",", ":"))
