"""What the bridge publishes: gateway info, discovery, drive states, availability and events.

The poller never waits for the broker: it hands states to the bounded `Outbox` and returns; `run`
drains it while connected. Events come from the store (`gateway.store`), where they were written
first: `forward_events` publishes them in id order and marks each delivered only once the broker
acknowledged it (QoS 1), so an outage or a restart loses none.

A drive's state is published when it has news by its report-by-exception rules
(`gateway.profile.report_by_exception`; a drive's from `mqtt.report` and its own `report`, by
default any change but `last_seen`'s; a device's points by their device file's rules over
`mqtt.report.devices`, its alarm flags on any change) or every
`publish_interval_s`, retained, so a dashboard that subscribes late still gets it at once; an
availability is published once per connection and change. What a broken connection kept from
being published goes back to the outbox, to go out after the next connect.
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Awaitable, Callable, Sequence

import aiomqtt

from gateway import __version__
from gateway.mqtt.connection import OFFLINE, ONLINE
from gateway.mqtt.discovery import discovery_messages
from gateway.mqtt.outbox import Outbox, Pending
from gateway.mqtt.requests import Json, dump
from gateway.mqtt.stats import BridgeStats
from gateway.mqtt.topics import Topics
from gateway.poller import Poller
from gateway.poller.drive_state import iso_time
from gateway.profile.report_by_exception import ExceptionReport
from gateway.profile.telemetry import Telemetry
from gateway.settings import DriveSettings, MqttSettings
from gateway.settings.mqtt import DriveReporting
from gateway.store import EventStore, EventType
from gateway.store.outage_rows import Gap, KeptSample

log = logging.getLogger(__name__)

QOS = 1
PUBLISH_TICK_S = 1.0
"""How often the publisher looks again when nothing new came (the periodic republish)."""
EVENT_BATCH = 100
"""Events read from the store at a time; each is still published and acknowledged in turn."""


def exception_report(mqtt: MqttSettings, drive: DriveSettings) -> ExceptionReport:
    """A drive's report by exception: a device file's points by their own rules over
    `mqtt.report.devices`, a drive's keys by `mqtt.report` and its own `report` (the JSON state's
    and Sparkplug's DDATA alike)."""
    if drive.profile.typed_points:
        return ExceptionReport(drive.profile.typed_points, mqtt.device_reporting)
    rules = mqtt.reporting.get(drive.name, DriveReporting())
    return ExceptionReport.of_keys(rules.default, rules.keys)


async def forward_stored(
    events: EventStore, publish: Callable[[str], Awaitable[None]], box: str | None
) -> None:
    """Publish what `events` holds for the broker, oldest first, until cancelled or `publish`
    fails; each one marked delivered once acknowledged (`publish` returns on the PUBACK: QoS
    1), so it goes out once. `box`: with `redundancy:`, this box's name, in each event.

    One forwarder at a time per store (`EventStore.forwarding`): the bridge's on a gateway that
    serves its lines, the role connection's on a redundant box that doesn't (`gateway.mqtt.
    role`: a standby hands over its own backlog), never both at once."""
    async with events.forwarding:
        events.redeliver()  # what the last connection sent unacknowledged goes again
        while True:
            batch = await events.undelivered(EVENT_BATCH)
            if not batch:
                await events.wait_stored(PUBLISH_TICK_S)
                continue
            acknowledged: list[int] = []
            try:
                for event in batch:
                    data = event.payload() if box is None else {**event.payload(), "box": box}
                    await publish(dump(data))
                    acknowledged.append(event.id)  # QoS 1: publish returned on the PUBACK
            finally:
                events.delivered(acknowledged)


class Publisher:
    def __init__(
        self,
        mqtt: MqttSettings,
        drives: Sequence[DriveSettings],
        topics: Topics,
        outbox: Outbox,
        poller: Poller,
        stats: BridgeStats,
        events: EventStore,
    ) -> None:
        self.mqtt = mqtt
        self.drives = drives
        self.topics = topics
        self.outbox = outbox
        self.poller = poller
        self.stats = stats
        self.events = events
        self.box: str | None = None
        """With `redundancy:`, this box's name, in every event it publishes: the two boxes'
        stores number their events each on its own, so a consumer tells them by box and id."""
        self._published: dict[str, float] = {}
        """Drive → the monotonic time its state was last published."""
        self._availability: dict[str, bool] = {}
        """Drive → the availability last published on this connection."""
        self._reports = {d.name: exception_report(mqtt, d) for d in drives}
        """Drive or device → what its keys (points) last published said."""

    # -- once per connection -------------------------------------------------------------------

    async def info(self, client: aiomqtt.Client) -> None:
        await self.keep(client, self.topics.bridge_info, self._info())

    async def catch_up(self, client: aiomqtt.Client) -> None:
        """After (re)connecting: discovery, every drive's availability and last state."""
        if self.mqtt.homeassistant_discovery:
            await self.discovery(client)
        self._published.clear()
        self._availability.clear()
        for drive in self.poller.drives:
            online = self.poller.availability(drive)
            if online is not None:
                await self._publish_availability(client, drive, online)
            telemetry = self.poller.telemetry(drive)
            if "last_seen" in telemetry:
                await self.state(client, drive, telemetry, force=True)

    def discovery_topics(self) -> set[str]:
        """The discovery configs this gateway offers now (none with discovery off)."""
        if not self.mqtt.homeassistant_discovery:
            return set()
        return {topic for topic, _ in discovery_messages(self.mqtt, self.drives, self.topics)}

    async def discovery(self, client: aiomqtt.Client) -> None:
        messages = discovery_messages(
            self.mqtt, self.drives, self.topics, self.poller.max_frequency_hz
        )
        for topic, payload in messages:
            await self.keep(client, topic, payload)
        log.info("MQTT: Home Assistant discovery published (%d entities)", len(messages))

    # -- while connected -----------------------------------------------------------------------

    async def run(self, client: aiomqtt.Client) -> None:
        """Drain the outbox for as long as the connection lasts."""
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

    async def forward_events(self, client: aiomqtt.Client) -> None:
        """Publish what the store holds for the broker (`forward_stored`), for as long as the
        connection lasts."""

        async def publish(payload: str) -> None:
            await self.publish(client, self.topics.bridge_event, payload)

        await forward_stored(self.events, publish, self.box)

    async def state(
        self, client: aiomqtt.Client, drive: str, telemetry: Telemetry, force: bool = False
    ) -> None:
        reading = {k: v for k, v in telemetry.items() if k != "last_seen"}
        last = self._published.get(drive)
        now = time.monotonic()
        report = self._reports.get(drive)
        if not force and last is not None:
            quiet = report is not None and not report.news(reading, now)
            if quiet and now - last < self.mqtt.publish_interval_s:
                return
        await self.keep(client, self.topics.drive_state(drive), dump(telemetry))
        self._published[drive] = now
        if report is not None:
            report.published(reading, now)

    async def history(self, client: aiomqtt.Client, drive: str, samples: list[KeptSample]) -> bool:
        """Values polled while the broker was away, in the order polled: one message of
        `{"drive", "samples": [{"time", <key>: <value>...}]}` on `<base>/<drive>/history`, each
        sample the values that were news at that poll (all of them at an outage's first)."""
        kept: list[Json] = [{"time": iso_time(s.time), **s.values} for s in samples]
        await self.publish(
            client,
            self.topics.history(drive),
            dump({"drive": drive, "samples": kept}),
            qos=self.mqtt.publish_qos,
        )
        return True

    async def history_gap(self, client: aiomqtt.Client, gap: Gap) -> None:
        """What the outage buffer could not hold: `{"drive", "gap": {"from", "to", "samples"}}`
        on the drive's history topic, before the samples after it."""
        data: Json = {"from": iso_time(gap.start), "to": iso_time(gap.end), "samples": gap.samples}
        payload = dump({"drive": gap.drive, "gap": data})
        await self.publish(
            client, self.topics.history(gap.drive), payload, qos=self.mqtt.publish_qos
        )

    async def answer(self, client: aiomqtt.Client, topic: str, response: Json) -> None:
        """A command's answer; when the connection is gone, there is nobody to tell."""
        with contextlib.suppress(aiomqtt.MqttError):
            await self.respond(client, topic, response)

    async def respond(self, client: aiomqtt.Client, topic: str, response: Json) -> None:
        """A command's answer, at `mqtt.publish_qos`: it is never sent again after a lost
        connection, so an acknowledgement would tell nobody anything."""
        await self.publish(client, topic, dump(response), qos=self.mqtt.publish_qos)

    async def clear_retained(self, client: aiomqtt.Client, topic: str) -> None:
        """Remove a retained command from the broker (an empty retained publish), and say so in
        an event: left there, it would run for the next subscriber."""
        with contextlib.suppress(aiomqtt.MqttError):
            await self.publish(client, topic, "", retain=True, qos=self.mqtt.publish_qos)
        log.warning("MQTT: a retained command on %s was refused and cleared from the broker", topic)
        drive = self.topics.drive_of(topic)
        data: Json = {"drive": drive or "bridge", "topic": topic}
        self.events.record(EventType.RETAINED_COMMAND_CLEARED, data, drive=drive)

    async def clear_command_topic(self, client: aiomqtt.Client, topic: str) -> None:
        """Remove whatever may be retained on a command's topic, once the command ran (MQTT
        3.1.1: the dispatcher's `clear_after_run`); quietly, as it is most often nothing."""
        await self.publish(client, topic, "", retain=True, qos=self.mqtt.publish_qos)
        log.debug("MQTT: %s cleared after its command ran (MQTT 3.1.1)", topic)

    async def keep(self, client: aiomqtt.Client, topic: str, payload: str) -> None:
        """A retained message the gateway publishes again on every connection (and a state
        every `publish_interval_s`): at `mqtt.publish_qos`, the latest one wins."""
        await self.publish(client, topic, payload, retain=True, qos=self.mqtt.publish_qos)

    async def publish(
        self,
        client: aiomqtt.Client,
        topic: str,
        payload: str,
        retain: bool = False,
        qos: int = QOS,
    ) -> None:
        await client.publish(topic, payload, qos=qos, retain=retain)
        self.stats.published += 1

    # -- inside ----------------------------------------------------------------------------------

    async def _publish_pending(self, client: aiomqtt.Client, pending: Pending) -> None:
        """Publish and remove each item in turn: what is left in `pending` was not sent."""
        while pending.availability:
            drive, online = next(iter(pending.availability.items()))
            await self._publish_availability(client, drive, online)
            del pending.availability[drive]
        while pending.states:
            drive, telemetry = next(iter(pending.states.items()))
            await self.state(client, drive, telemetry)
            del pending.states[drive]

    async def _publish_availability(self, client: aiomqtt.Client, drive: str, online: bool) -> None:
        if self._availability.get(drive) is online:
            return  # already said, on this connection
        payload = ONLINE if online else OFFLINE
        await self.keep(client, self.topics.availability(drive), payload)
        self._availability[drive] = online

    def _info(self) -> str:
        return dump(
            {
                "gateway_id": self.mqtt.gateway_id,
                "version": __version__,
                "commands_enabled": self.mqtt.commands_enabled,
                "drives": [
                    {
                        "name": d.name,
                        "model": d.model,
                        "bus": d.bus,
                        "address": d.address,
                        "unit_id": d.unit_id,
                    }
                    for d in self.drives
                ],
            }
        )
