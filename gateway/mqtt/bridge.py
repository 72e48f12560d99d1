"""The MQTT bridge: telemetry out to the broker, commands in to the drives.

A feature of the application, put together from its jobs:

- `session`: the connection (connect, backoff, TLS, subscriptions, online and offline);
- `publisher`: info, discovery, what the poller hands the `outbox` (de-duplicated), and the
  events the store keeps until the broker acknowledged them;
- `event_link`: the connection the events go out on (the session's, or one of their own);
- `dispatcher`: each received message to its kind (`kinds`), run in its lane (`lanes`).

With `mqtt.sparkplug`, the Sparkplug B edge node (`gateway.sparkplug`), which the application
builds and hands in (`BesideTheBridge`), runs beside it on its own connection: the bridge hands
it what the poller hands the bridge, and starts and stops it (both goodbyes at once: the two fit
in the time one feature has to stop).

On every connection: online, info, subscriptions, discovery, every drive's availability and
state, then the publisher and the dispatcher run side by side until the connection is lost; what
had not started in the lanes is dropped with it (a command that came on a lost connection never
runs after the next one is up). A command whose turn comes later than `command_max_age_s` after
it came is answered `stale` instead of being run; a lane that is full answers `busy`.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Awaitable, Sequence
from typing import Protocol

import aiomqtt

from gateway.mqtt.alone import check_alone
from gateway.mqtt.commands import CommandDrive, Commands
from gateway.mqtt.connection import MQTT_3_1_1, MQTT_5
from gateway.mqtt.discovery_cleanup import own_discovery_topics, remove_stale_entities
from gateway.mqtt.dispatcher import ClearAfterRun, Dispatcher
from gateway.mqtt.event_link import EventLink
from gateway.mqtt.kinds import AnySet, Context, command_kinds
from gateway.mqtt.lanes import Lanes
from gateway.mqtt.outage import OutageRecorder
from gateway.mqtt.outbox import Outbox
from gateway.mqtt.publisher import Publisher
from gateway.mqtt.session import Session
from gateway.mqtt.stats import BridgeStats, SessionStatus
from gateway.mqtt.topics import Topics
from gateway.poller import DriveEvent, Poller
from gateway.profile.telemetry import Telemetry
from gateway.routing import Router
from gateway.settings import DriveSettings, MqttSettings
from gateway.store import EventStore
from gateway.tasks import ServiceTasks, side_by_side

log = logging.getLogger(__name__)

STOP_TASK_BUDGET_S = 0.6
"""With the offline message, inside the 1 s the application gives each feature to stop."""
MAX_WAITING_PER_LANE = 16
"""Messages for one drive waiting for their turn; past this they are answered `busy`."""


class BesideTheBridge(Protocol):
    """A part on a connection of its own that takes what the poller hands the bridge, started
    and stopped with it: the Sparkplug B edge node (`gateway.sparkplug.edge_node.SparkplugNode`)."""

    def state_updated(self, drive: str, telemetry: Telemetry) -> None: ...

    def availability_changed(self, drive: str, online: bool) -> None: ...

    async def start(self) -> None: ...

    async def say_offline(self) -> None:
        """Its goodbye on its connection, bounded (said beside the bridge's own)."""

    async def end_tasks(self) -> None:
        """Its connection's work ended, bounded."""


class MqttBridge:
    def __init__(
        self,
        mqtt: MqttSettings,
        served: Sequence[DriveSettings],
        router: Router,
        poller: Poller,
        tasks: ServiceTasks,
        events: EventStore,
        beside: BesideTheBridge | None = None,
    ) -> None:
        self.stats = BridgeStats()
        self.topics = Topics(mqtt.base_topic)
        self.outbox = Outbox()
        self.lanes = Lanes(MAX_WAITING_PER_LANE, tasks)
        self.publisher = Publisher(
            mqtt, served, self.topics, self.outbox, poller, self.stats, events
        )
        drives = {
            # The drive's corrected profile (faults, identification, ready bit), as the poller's.
            d.name: CommandDrive(d.name, router.route_for_drive(d.name), d.profile)
            for d in served
        }
        self.commands = Commands(mqtt, router, poller, drives, events)
        self.context = context = Context(
            self.topics,
            self.commands,
            self.publisher,
            poller,
            self.lanes,
            self.stats,
            mqtt.gateway_id,
            mqtt.discovery_prefix,
            events,
        )
        kinds = command_kinds(context, drives, mqtt.homeassistant_discovery)
        self.session = Session(mqtt, self.topics, self.stats, tasks, self._connected, self._lost)
        self.dispatcher = Dispatcher(
            kinds,
            self.lanes,
            self.publisher.answer,
            self.stats,
            self.publisher.clear_retained,
            self._clear_after_run,
            AnySet(context),
        )
        self.event_link = EventLink(self.session, self.publisher)
        self.settings, self.tasks = mqtt, tasks
        self._discovery_cleaned = False
        self.beside = beside  # the Sparkplug B edge node (`mqtt.sparkplug`); None: not enabled
        self.outage = OutageRecorder("json", events, self.session.connected.is_set)

    @property
    def connected(self) -> asyncio.Event:
        return self.session.connected

    def status(self) -> SessionStatus:
        """The session in a few figures, read from what the parts keep anyway: cheap."""
        session, settings = self.session, self.settings
        store = self.publisher.events.stats
        return SessionStatus(
            broker=session.server_name,
            tls=settings.tls,
            protocol="5" if session.protocol == MQTT_5 else "3.1.1",
            connected=session.connected.is_set(),
            connected_since=session.connected_since,
            queued=store.undelivered,
            dropped=store.events_dropped,
            last_error=session.last_error,
            last_error_at=session.last_error_at,
            connects=self.stats.connects,
            connect_failures=self.stats.connect_failures,
            published=self.stats.published,
        )

    # -- PollListener: called by the poller, return at once ----------------------------------

    def state_updated(self, drive: str, telemetry: Telemetry) -> None:
        self.outbox.put_state(drive, telemetry)
        self.outage.state_updated(drive, telemetry)
        if self.beside is not None:
            self.beside.state_updated(drive, telemetry)

    def availability_changed(self, drive: str, online: bool) -> None:
        self.outbox.put_availability(drive, online)
        if self.beside is not None:
            self.beside.availability_changed(drive, online)

    def drive_event(self, event: DriveEvent) -> None:
        pass  # events reach the broker from the store, where the store's own listener put them

    # -- lifecycle ---------------------------------------------------------------------------

    async def start(self, checked: bool = False) -> None:
        """`checked`: a reload has just made sure no other gateway is live on our base topic
        (`check_alone`, which raises BrokerShared); a start makes sure here."""
        if not checked:
            await check_alone(self.settings, self.topics)
        await self.session.start()
        if self.beside is not None:
            await self.beside.start()

    async def stop(self) -> None:
        beside = self.beside
        # Both goodbyes at once, then both connections' ends at once: the two fit in the time
        # one has (each step is bounded).
        offline: list[Awaitable[object]] = [self.session.say_offline()]
        if beside is not None:
            offline.append(beside.say_offline())
        await asyncio.gather(*offline)
        # Commands being carried out are cut off: the buses are closed by now anyway.
        stopping: list[Awaitable[object]] = [
            self.lanes.close(STOP_TASK_BUDGET_S),
            self.session.stop(STOP_TASK_BUDGET_S),
        ]
        if beside is not None:
            stopping.append(beside.end_tasks())
        await asyncio.gather(*stopping)

    # -- one connection ----------------------------------------------------------------------

    async def _connected(self, client: aiomqtt.Client) -> None:
        await self.publisher.info(client)
        await self.session.subscribe(client, self.dispatcher.topics)
        # Online only now: a client that sends a request on seeing it must find us listening.
        await self.session.say_online(client)
        await self.publisher.catch_up(client)
        self.session.connected.set()
        if not self._discovery_cleaned:
            self._discovery_cleaned = True
            self.tasks.start("mqtt:discovery-cleanup", self._clean_discovery())
        await side_by_side(
            {
                "mqtt:publish": self.publisher.run(client),
                "mqtt:events": self.event_link.run(client),
                "mqtt:receive": self.dispatcher.run(client),
                "mqtt:history": self.outage.deliver(
                    lambda drive, samples: self.publisher.history(client, drive, samples),
                    lambda gap: self.publisher.history_gap(client, gap),
                ),
            },
            STOP_TASK_BUDGET_S,
        )

    async def _clean_discovery(self) -> None:
        """Once per start: entities published before and no longer offered are removed."""
        pattern = own_discovery_topics(self.settings.discovery_prefix, self.settings.gateway_id)
        try:
            await remove_stale_entities(
                self.session.side_client("cleanup"), pattern, self.publisher.discovery_topics()
            )
        except aiomqtt.MqttError as exc:
            # Not worth a restart: the broker went away meanwhile; the next start tries again.
            log.info("MQTT: stale Home Assistant entities not checked: %s", exc)

    def _clear_after_run(self) -> ClearAfterRun | None:
        """Under MQTT 3.1.1 only: with MQTT 5 a retained command keeps its flag
        (retain-as-published), is refused and cleared as such."""
        if self.session.protocol == MQTT_3_1_1:
            return self.publisher.clear_command_topic
        return None

    def _lost(self) -> None:
        self.lanes.drop_waiting()
