"""`SparkplugNode`: the gateway as a Sparkplug B edge node on its own MQTT connection.

    connect   the will is an NDEATH whose `bdSeq` goes up by one (0-255) at every CONNECT,
              across restarts too (kept in the store, committed before the CONNECT): the
              NBIRTH that follows carries the same `bdSeq`, so a host pairs them, and a
              restart's NBIRTH has a `bdSeq` the host has not seen last. The specification
              has each new CONNECT's bdSeq one more than the previous CONNECT's
              (`message-flow-edge-node-birth-publish-will-message-payload-bdSeq`,
              `payloads-ndeath-bdseq`: "any new CONNECT packet must increment the bdSeq number
              ... compared to what was in the previous CONNECT packet"), starting at zero
              (`topics-nbirth-bdseq-increment`); the TCK's monitor checks exactly that for
              every CONNECT of an edge node id it sees, a restart's included. So the count is
              the edge node's, not the process's: 0 with a new store, and on after a restart
    subscribe NCMD, every drive's DCMD, and the primary host's STATE when one is named
    birth     (once the primary host is online, if named) NBIRTH with `seq` 0, then a DBIRTH
              per drive that is online, `seq` counting up and wrapping 255 → 0
    report    what the poller hands over: DDATA with the metrics that have news (aliases only),
              a DBIRTH when a drive comes (back) online, a DDEATH when it goes offline
    outage    while the node can't publish (no connection, not born, the primary host offline)
              each poll's news is kept in the store's outage buffer (`gateway.mqtt.outage`);
              once born again it goes out beside the live values as DDATA whose metrics are
              `is_historical`, each with the time it was polled, in order; what the buffer
              could not hold is a null historical metric of each at the gap's start
    rebirth   NCMD "Node Control/Rebirth" = true: NBIRTH and DBIRTHs again (same bdSeq: the
              will of this connection), `seq` from 0
    commands  DCMD in a lane per drive, through `gateway.mqtt.commands` as `/set` (retained and
              stale refusal, `commands_enabled`, the write, the `command` event); a retained
              one is cleared from the broker; the new value is the acknowledgement, in DDATA
    host      the primary host's STATE going offline: NDEATH, disconnect, and the next of
              `mqtt.servers` (the specification's high availability); until it is online again
              nothing is published. NCMD "Node Control/Next Server" = true does the same.
    stop      NDEATH ourselves, then (MQTT 5) a DISCONNECT with reason code 0x04 "Disconnect
              with Will Message", which every DISCONNECT of this connection carries
              (`payloads-ndeath-will-message-publisher-disconnect-mqtt50`): the broker publishes
              the will as well, an NDEATH of the same bdSeq, which a host ignores

The connection loop (backoff, TLS, the server list, MQTT 5 with retain-as-published) is the JSON
bridge's `Session`, with this node's will and client id (`<client_id>-sparkplug`).
"""

from __future__ import annotations

import asyncio
import dataclasses
import json
import logging
import time
from collections.abc import Callable, Sequence
from typing import Final

import aiomqtt

from gateway import __version__
from gateway.logs import repeated
from gateway.mqtt.commands import CommandDrive, Commands
from gateway.mqtt.dispatcher import Incoming
from gateway.mqtt.lanes import Lanes
from gateway.mqtt.outage import OutageRecorder
from gateway.mqtt.outbox import Outbox, Pending
from gateway.mqtt.publisher import exception_report
from gateway.mqtt.requests import Json
from gateway.mqtt.session import Session
from gateway.mqtt.stats import BridgeStats
from gateway.mqtt.topics import Topics
from gateway.poller import DriveEvent, Poller
from gateway.profile.telemetry import Telemetry
from gateway.routing import Router
from gateway.settings import DriveSettings, MqttSettings
from gateway.settings.mqtt import SparkplugSettings
from gateway.sparkplug import payload
from gateway.sparkplug.bd_seq import BirthDeathSequence
from gateway.sparkplug.commands import device_command
from gateway.sparkplug.history import HistoricalData
from gateway.sparkplug.host import PrimaryHost
from gateway.sparkplug.metrics import Aliases, DeviceMetrics
from gateway.sparkplug.payload import BirthMetric
from gateway.sparkplug.topics import SparkplugTopics, host_state
from gateway.store import EventStore, EventType
from gateway.tasks import ServiceTasks, side_by_side

log = logging.getLogger(__name__)

QOS_DATA: Final = 0
"""NBIRTH, DBIRTH, DDATA, DDEATH: QoS 0, never retained (specification 3.0)."""
QOS_DEATH: Final = 1
"""NDEATH (the will, and our own at a clean stop) and the subscriptions: QoS 1."""
REBIRTH: Final = "Node Control/Rebirth"
NEXT_SERVER: Final = "Node Control/Next Server"
NODE: Final = ""
"""The node's own metrics' "device" among the aliases."""
STOP_TASK_BUDGET_S: Final = 0.6
MAX_WAITING_PER_LANE: Final = 16


class SparkplugNode:
    def __init__(
        self,
        mqtt: MqttSettings,
        sparkplug: SparkplugSettings,
        served: Sequence[DriveSettings],
        router: Router,
        poller: Poller,
        tasks: ServiceTasks,
        events: EventStore,
    ) -> None:
        self.settings = sparkplug
        self.topics = SparkplugTopics(sparkplug.group_id, sparkplug.edge_node_id)
        self.stats = BridgeStats()
        self.outbox = Outbox()
        self.lanes = Lanes(MAX_WAITING_PER_LANE, tasks)
        self.aliases = Aliases()
        self.devices = {
            d.name: DeviceMetrics(
                d.name, d.profile, exception_report(mqtt, d), self.aliases, mqtt.commands_enabled
            )
            for d in served
        }
        drives = {
            d.name: CommandDrive(d.name, router.route_for_drive(d.name), d.profile) for d in served
        }
        self.commands = Commands(mqtt, router, poller, drives, events, source="sparkplug")
        self.poller = poller
        self.events = events
        self.gateway_id = mqtt.gateway_id
        self.host = PrimaryHost(sparkplug.primary_host_id) if sparkplug.primary_host_id else None
        self.bd_seq = BirthDeathSequence(events, sparkplug.group_id, sparkplug.edge_node_id)
        """The `bdSeq` of the last CONNECT's will; the NBIRTH repeats it."""
        self.born: list[Callable[[], None]] = []
        """Told after each NBIRTH (a redundant box's role announcement carries the bdSeq)."""
        self.seq = payload.SequenceNumber()
        self._wake = asyncio.Event()
        """Something to publish, a rebirth asked for, or the primary host changed."""
        self._rebirth = False
        self._leave: str | None = None
        """Why this connection is to end for the next server (None: it isn't)."""
        self._born = asyncio.Event()
        """Set once this connection's NBIRTH is out: the birth comes before anything else the
        node publishes (clearing a retained DCMD waits for it)."""
        self.outage = OutageRecorder("sparkplug", events, self.reaches_a_host)
        own = dataclasses.replace(mqtt, client_id=f"{mqtt.client_id}-sparkplug")
        self.session = Session(
            own, Topics(mqtt.base_topic), self.stats, tasks, self._connected, self._lost, self
        )

    @property
    def connected(self) -> asyncio.Event:
        return self.session.connected

    def continue_from(self, old: SparkplugNode) -> None:
        """A reload's new node after `old`: the bdSeq counts on (from the store, or from `old`'s
        where the store could not keep it)."""
        self.bd_seq.value = old.bd_seq.value

    # -- PollListener, through the bridge: return at once -----------------------------------

    def state_updated(self, drive: str, telemetry: Telemetry) -> None:
        if drive in self.devices:
            self.outbox.put_state(drive, telemetry)
            self.outage.state_updated(drive, telemetry)
            self._wake.set()

    def availability_changed(self, drive: str, online: bool) -> None:
        if drive in self.devices:
            self.outbox.put_availability(drive, online)
            self._wake.set()

    def drive_event(self, event: DriveEvent) -> None:
        pass

    # -- Presence, for the session ----------------------------------------------------------

    disconnect_with_will = True
    """Sparkplug 3.0, `payloads-ndeath-will-message-publisher-disconnect-mqtt50`: "If the Edge
    Node is using MQTT 5.0 and it sends an MQTT DISCONNECT packet, the MQTT v5.0 'Disconnect
    with Will Message' reason code MUST be set in the DISCONNECT packet"."""

    async def will(self) -> aiomqtt.Will:
        """The NDEATH of the CONNECT about to be sent: the next `bdSeq`, from the store (the
        module's docstring says why)."""
        death = payload.node_death(await self.bd_seq.next(), _now_ms())
        return aiomqtt.Will(self.topics.node("NDEATH"), death, qos=QOS_DEATH, retain=False)

    async def farewell(self, client: aiomqtt.Client, timeout_s: float) -> None:
        death = payload.node_death(self.bd_seq.value, _now_ms())
        await client.publish(
            self.topics.node("NDEATH"), death, qos=QOS_DEATH, retain=False, timeout=timeout_s
        )

    # -- lifecycle --------------------------------------------------------------------------

    async def start(self) -> None:
        await self.session.start()

    async def stop(self) -> None:
        await self.say_offline()
        await self.end_tasks()

    async def say_offline(self) -> None:
        """Our NDEATH, if connected (a clean disconnect sends no will)."""
        await self.session.say_offline()

    async def end_tasks(self) -> None:
        """Cancel the connection and the commands under way, each within its budget."""
        await asyncio.gather(
            self.lanes.close(STOP_TASK_BUDGET_S), self.session.stop(STOP_TASK_BUDGET_S)
        )

    # -- one connection ---------------------------------------------------------------------

    async def _connected(self, client: aiomqtt.Client) -> None:
        self._leave = None
        subscriptions = [self.topics.node("NCMD"), self.topics.device_commands]
        if self.host is not None:
            # Offline until this broker's retained STATE says otherwise; its timestamps are
            # compared with this broker's only (the host's birth and will share one).
            self.host.online, self.host.timestamp = False, -1
            subscriptions.append(host_state(self.host.host_id))
        await self.session.subscribe(client, subscriptions, qos=QOS_DEATH)
        self.session.connected.set()
        await side_by_side(
            {
                "sparkplug:publish": self._publish(client),
                "sparkplug:receive": self._receive(client),
                "sparkplug:history": self._history(client),
            },
            STOP_TASK_BUDGET_S,
        )

    def reaches_a_host(self) -> bool:
        """Whether what is polled now reaches a host: born, and the primary host online."""
        return self._born.is_set() and (self.host is None or self.host.online)

    async def _history(self, client: aiomqtt.Client) -> None:
        await self._born.wait()

        async def publish(drive: str, metrics: list[payload.HistoricalMetric]) -> None:
            data = payload.history(self.seq.next(), _now_ms(), metrics)
            await self._send(client, self.topics.device("DDATA", drive), data)

        history = HistoricalData(self.devices, self.poller, publish)
        await self.outage.deliver(history.send, history.mark)

    def _lost(self) -> None:
        self._born.clear()
        self.lanes.drop_waiting()

    async def _publish(self, client: aiomqtt.Client) -> None:
        while True:
            await self._wait_for_host()
            self._rebirth = False
            await self._birth(client)
            while not self._rebirth:
                await self._wake.wait()
                self._wake.clear()
                if self.host is not None and not self.host.online:
                    self._leave = f"primary host {self.host.host_id} went offline"
                if self._leave is not None:
                    await self.farewell(client, STOP_TASK_BUDGET_S)
                    raise _leaving_server(self._leave)
                pending = self.outbox.take()
                try:
                    await self._report(client, pending)
                finally:
                    if pending:
                        self.outbox.restore(pending)
            log.info("Sparkplug: rebirth")

    async def _wait_for_host(self) -> None:
        """Until the primary host (if named) is online. On a broker where it isn't, with other
        brokers to try, the next one is tried (where the host may be)."""
        while self.host is not None and not self.host.online:
            if self.host.timestamp >= 0 and len(self.session.mqtt.servers) > 1:
                raise _leaving_server(f"primary host {self.host.host_id} is offline here")
            if self._leave is not None:
                raise _leaving_server(self._leave)
            await self._wake.wait()
            self._wake.clear()

    async def _birth(self, client: aiomqtt.Client) -> None:
        self.outbox.take()  # the births carry the values of now
        for device in self.devices.values():
            device.forget()
        birth = payload.birth(self.seq.restart(), _now_ms(), self._node())
        await self._send(client, self.topics.node("NBIRTH"), birth)
        self._born.set()
        for drive, device in self.devices.items():
            telemetry = self.poller.telemetry(drive)
            if self.poller.availability(drive) is not False and "last_seen" in telemetry:
                await self._device_birth(client, device, telemetry)
        log.info(
            "Sparkplug: born as %s (bdSeq %d, %d devices)",
            self.topics.node("NBIRTH"),
            self.bd_seq.value,
            sum(device.born for device in self.devices.values()),
        )
        for listener in self.born:
            listener()

    def _node(self) -> list[BirthMetric]:
        return [
            BirthMetric(
                payload.BD_SEQ,
                self.aliases.of(NODE, payload.BD_SEQ),
                payload.INT64,
                self.bd_seq.value,
            ),
            # No alias for it: a host must be able to ask for a rebirth knowing nothing of this
            # node's aliases (the specification forbids one).
            BirthMetric(REBIRTH, None, payload.BOOLEAN, False, {"readOnly": False}),
            BirthMetric(NEXT_SERVER, None, payload.BOOLEAN, False, {"readOnly": False}),
            BirthMetric(
                "Node Info/gateway_id",
                self.aliases.of(NODE, "Node Info/gateway_id"),
                payload.STRING,
                self.gateway_id,
            ),
            BirthMetric(
                "Node Info/version",
                self.aliases.of(NODE, "Node Info/version"),
                payload.STRING,
                __version__,
            ),
        ]

    async def _report(self, client: aiomqtt.Client, pending: Pending) -> None:
        """Publish and remove each item in turn: what is left in `pending` was not sent."""
        while pending.availability:
            drive, online = next(iter(pending.availability.items()))
            device = self.devices[drive]
            if not online and device.born:
                topic = self.topics.device("DDEATH", drive)
                await self._send(client, topic, payload.device_death(self.seq.next(), _now_ms()))
                device.forget()
            del pending.availability[drive]
        while pending.states:
            drive, telemetry = next(iter(pending.states.items()))
            device = self.devices[drive]
            if self.poller.availability(drive) is not False:
                await self._device_report(client, device, telemetry)
            del pending.states[drive]

    async def _device_report(
        self, client: aiomqtt.Client, device: DeviceMetrics, telemetry: Telemetry
    ) -> None:
        changes = device.changes(telemetry, time.monotonic()) if device.born else None
        if changes is None:
            await self._device_birth(client, device, telemetry)
        elif changes:
            data = payload.data(self.seq.next(), _now_ms(), changes)
            await self._send(client, self.topics.device("DDATA", device.device), data)

    async def _device_birth(
        self, client: aiomqtt.Client, device: DeviceMetrics, telemetry: Telemetry
    ) -> None:
        metrics = device.birth(telemetry, time.monotonic())
        birth = payload.birth(self.seq.next(), _now_ms(), metrics)
        await self._send(client, self.topics.device("DBIRTH", device.device), birth)

    async def _send(self, client: aiomqtt.Client, topic: str, data: bytes) -> None:
        await client.publish(topic, data, qos=QOS_DATA, retain=False)
        self.stats.published += 1

    # -- received ---------------------------------------------------------------------------

    async def _receive(self, client: aiomqtt.Client) -> None:
        async for message in client.messages:
            data = message.payload if isinstance(message.payload, bytes) else b""
            incoming = Incoming(str(message.topic), data, bool(message.retain), time.monotonic())
            try:
                self._dispatch(client, incoming)
            except Exception:
                log.exception("Sparkplug: handling a message on %s failed", incoming.topic)

    def _dispatch(self, client: aiomqtt.Client, incoming: Incoming) -> None:
        topic = incoming.topic
        if self.host is not None and topic == host_state(self.host.host_id):
            if self.host.update(incoming.payload):
                self._wake.set()
            return
        if not incoming.payload:
            return  # a retained message cleared (ours, or someone's)
        if topic == self.topics.node("NCMD"):
            self._node_command(incoming)
            return
        drive = self.topics.device_of(topic)
        if drive is None or drive not in self.devices:
            log.warning(
                "Sparkplug: a DCMD for %s, which is no device of this node",
                topic,
                extra=repeated("sparkplug-no-device"),
            )
            return
        self.stats.commands_received += 1
        if incoming.retained:
            self.lanes.submit("retained", lambda: self._clear_retained(client, incoming))

        async def job() -> None:
            await self._device_command(drive, incoming)

        if not self.lanes.submit(f"sparkplug:{drive}", job):
            self.stats.busy += 1
            log.warning(
                "Sparkplug: DCMD for %s refused: %d wait already",
                drive,
                MAX_WAITING_PER_LANE,
                extra=repeated("sparkplug-busy"),
            )

    def _node_command(self, incoming: Incoming) -> None:
        if incoming.retained:
            log.warning("Sparkplug: a retained NCMD ignored", extra=repeated("sparkplug-ncmd"))
            return
        try:
            received = payload.received(incoming.payload)
        except ValueError as exc:
            log.warning("Sparkplug: NCMD ignored: %s", exc, extra=repeated("sparkplug-ncmd"))
            return
        for metric in received.metrics:
            if metric.value is not True:
                continue
            if metric.name == REBIRTH:
                self._rebirth = True
            elif metric.name == NEXT_SERVER:
                self._leave = "a host asked for the next server (Node Control/Next Server)"
            else:
                log.warning(
                    "Sparkplug: NCMD for %s ignored: no such node metric",
                    metric.name,
                    extra=repeated("sparkplug-ncmd"),
                )
            self._wake.set()

    async def _device_command(self, drive: str, incoming: Incoming) -> None:
        # Anyone who may publish on the broker sends these as fast as he likes: each is
        # counted (`invalid_request`), the log has one line a minute of them.
        try:
            received = payload.received(incoming.payload)
        except ValueError as exc:
            self.commands.statuses["invalid_request"] += 1
            log.warning(
                "Sparkplug: DCMD for %s refused: %s", drive, exc, extra=repeated("sparkplug-dcmd")
            )
            return
        command = device_command(received, self.devices[drive])
        if command.problems:
            self.commands.statuses["invalid_request"] += 1
        for problem in command.problems:
            log.warning(
                "Sparkplug: DCMD for %s: %s", drive, problem, extra=repeated("sparkplug-dcmd")
            )
        target = self.commands.drives[drive]
        for set_payload in command.payloads:
            message = dataclasses.replace(incoming, payload=json.dumps(set_payload).encode())
            with self.commands.acknowledgement() as acknowledgement:
                admitted = self.commands.admit(message, acknowledgement, writes=True)
                acknowledgement.ok(await self.commands.set(target, admitted))
            answer = acknowledgement.response
            if answer.get("status") == "ok":
                log.info("Sparkplug: DCMD for %s done: %s", drive, answer.get("data"))
            else:
                log.warning(
                    "Sparkplug: DCMD for %s refused (%s): %s",
                    drive,
                    answer.get("error"),
                    answer.get("message"),
                    extra=repeated(f"sparkplug-refused-{answer.get('error')}"),
                )

    async def _clear_retained(self, client: aiomqtt.Client, incoming: Incoming) -> None:
        """Left on the broker, a retained DCMD would come again to every subscriber."""
        await self._born.wait()
        try:
            await client.publish(incoming.topic, b"", qos=QOS_DEATH, retain=True)
        except aiomqtt.MqttError:
            return
        log.warning("Sparkplug: a retained DCMD on %s was refused and cleared", incoming.topic)
        drive = self.topics.device_of(incoming.topic)
        data: Json = {"drive": drive, "topic": incoming.topic}
        self.events.record(EventType.RETAINED_COMMAND_CLEARED, data, drive=drive)


def _now_ms() -> int:
    return int(time.time() * 1000)


def _leaving_server(why: str) -> aiomqtt.MqttError:
    """Ends this connection the way a lost one ends: the session tries the next of
    `mqtt.servers` after its backoff, and logs `why` (the primary host is offline here, or a host
    asked for "Node Control/Next Server"). aiomqtt's own error, so the session needs no case of
    its own for it."""
    return aiomqtt.MqttError(why)
