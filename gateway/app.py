"""The application: wires the configured parts together and runs their lifecycle.

    startup   buses open their ports (in the background, with backoff), the TCP server listens,
              features (poller, MQTT bridge, metrics) start, then "ready" is reported; every
              background task (buses, poller, MQTT, the console's sampler, the service's
              SIGHUP listener and watchdog) runs in one TaskGroup: one that dies of a bug
              stops the service (`BusFailed`, `FeatureFailed`: exit code 1)
    serve     until the stop event is set (SIGTERM / SIGINT); with `redundancy:` the buses, the
              poller and the MQTT bridge run only while this gateway is the line's active
              master (`gateway.redundancy`, through `LineHandover`): a standby listens
    shutdown  stop accepting; queued requests are answered 0x0B; the transaction on the wire
              finishes; features stop (MQTT publishes offline); within 2 s in all

It does nothing itself but wiring: each part gets its dependencies passed in.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Awaitable, Callable, Coroutine, Mapping
from typing import TYPE_CHECKING, Any, Protocol

from gateway.bus import Bus, BusState
from gateway.bus.queue import Waiter
from gateway.errors import CannotListen, GatewayError, GatewayPathUnavailable, StandbyRefusal
from gateway.health import Phase, health_report
from gateway.modbus.functions import is_exception
from gateway.poller import Poller
from gateway.routing import RegisterCache, Router
from gateway.settings import (
    ConsoleSettings,
    GatewaySettings,
    MqttSettings,
    OpcUaSettings,
    drive_route,
)
from gateway.settings.reload import ReloadPlan
from gateway.settings.reload import plan as plan_reload
from gateway.store import EventStore, EventType
from gateway.store.modbus_writes import WriteTally
from gateway.tasks import ServiceTasks, cancel_and_wait
from gateway.tcp import ModbusTcpServer

if TYPE_CHECKING:
    from gateway.console.feature import ConsoleFeature
    from gateway.metrics import MetricsFeature
    from gateway.mqtt import MqttBridge
    from gateway.mqtt.role import RoleAnnouncer
    from gateway.mqtt.told import ToldBirth, ToldFaults
    from gateway.opcua.server import OpcUaServer
    from gateway.redundancy import Redundancy
    from gateway.sparkplug.edge_node import SparkplugNode

log = logging.getLogger(__name__)

SHUTDOWN_BUDGET_S = 1.5
FEATURE_STOP_S = 0.5
"""Time for the transaction on the wire and the answers in flight, inside the 2 s promise."""


class Feature(Protocol):
    """A part with a lifecycle; its constructor only stores its dependencies."""

    async def start(self) -> None: ...

    async def stop(self) -> None: ...


class Application:
    """The parts, each built by a function of its own and named here: the buses, the router,
    the Modbus-TCP server, the store, the write tally and the poller always; the MQTT bridge,
    /metrics, the OPC UA server and the console when their sections are configured (None
    when not). Nothing is
    found by asking whether an attribute exists."""

    def __init__(self, settings: GatewaySettings) -> None:
        self.settings = settings
        self.buses = {b.name: Bus(b) for b in settings.buses}
        self.router = Router(
            (drive_route(d, self.buses[d.bus]) for d in settings.drives), self.buses.values()
        )
        for bus in self.buses.values():
            bus.add_listener(self.router.on_drive_health)
        self.tasks = ServiceTasks()
        self._group: asyncio.TaskGroup | None = None
        self._bus_tasks: dict[str, asyncio.Task[None]] = {}
        """Each bus's `run`, by name: a reload that reopens a bus waits for its old one."""
        self.phase = Phase.STARTING
        self.events = EventStore(settings.store, self.tasks)
        for bus in self.buses.values():
            bus.add_port_listener(self.events.port_changed)
        self.writes = WriteTally(self.events, self._drive_of, self.tasks)
        self.requests = TcpRequests(self.router, self.writes)
        """What the Modbus-TCP server's requests go through."""
        self.tcp = ModbusTcpServer(settings.tcp, self.requests)
        self.poller = self._build_poller()
        self.mqtt: MqttBridge | None = None
        self.sparkplug: SparkplugNode | None = None
        """Beside the bridge's JSON topics, started and stopped by it (`mqtt.sparkplug`)."""
        if settings.mqtt is not None:
            self.sparkplug = self._build_sparkplug(settings.mqtt)
            self.mqtt = self._build_mqtt(settings.mqtt, self.sparkplug)
        self.metrics: MetricsFeature | None = None
        if settings.metrics is not None:
            from gateway.metrics import MetricsFeature  # prometheus-client only when asked for

            self.metrics = MetricsFeature(self, settings.metrics)
        self.opcua: OpcUaServer | None = None
        if settings.opcua is not None:
            self.opcua = self._build_opcua(settings.opcua)
        self.console: ConsoleFeature | None = None
        if settings.console is not None:
            self.console = self._build_console(settings.console)
        self.redundancy: Redundancy | None = None
        """With `redundancy:`, this gateway's role on its lines; None: it is their master."""
        self.announcer: RoleAnnouncer | None = None
        """With `redundancy:` and MQTT: this box's role, retained on the broker."""
        self.handover = LineHandover(self)
        if settings.redundancy is not None:
            self.redundancy = self.handover.build_redundancy()

    @property
    def features(self) -> list[Feature]:
        """The parts with a lifecycle, in the order they start (they stop in reverse): /metrics
        first and last, so /health answers while the others come and go; the store before
        every part that records events, so none is lost; the poller before the bridge and the
        console it feeds."""
        parts: tuple[Feature | None, ...] = (
            self.metrics,
            self.events,
            self.writes,
            self.poller,
            self.mqtt,
            self.opcua,
            self.console,
        )
        return [part for part in parts if part is not None]

    def _build_poller(self) -> Poller:
        """Polls feed the cache, the fault log and (when configured) the MQTT bridge and the
        console. It runs with no drive to poll too (a pure Modbus-TCP gateway, a site whose
        drives are still to come): a reload may add some."""
        from gateway.event_log import DriveEventLog

        settings = self.settings
        poller = Poller([d for d in settings.drives if settings.polled(d)], self.router, self.tasks)
        for bus in self.buses.values():
            bus.add_listener(poller.on_drive_health)
        poller.add_listener(DriveEventLog())
        poller.add_listener(self.events)
        poller.add_listener(self.events.history)  # the history of polled values
        poller.open_faults = self.events.open_faults  # no fault raised twice by a restart
        return poller

    def _build_mqtt(self, mqtt: MqttSettings, sparkplug: SparkplugNode | None) -> MqttBridge:
        """The bridge takes what the poller hands it (and hands it on to the Sparkplug node);
        it stops before the poller."""
        from gateway.mqtt import MqttBridge  # aiomqtt only loaded when MQTT is configured

        drives = self.settings.drives
        parts = (self.router, self.poller, self.tasks, self.events)
        bridge = MqttBridge(mqtt, drives, *parts, beside=sparkplug)
        self.poller.read_max_frequency = mqtt.homeassistant_discovery
        self.poller.add_listener(bridge)
        return bridge

    def _build_opcua(self, opcua: OpcUaSettings) -> OpcUaServer:
        """The OPC UA server takes what the poller hands it and sends writes and methods
        through the command path; a reload's drives added or removed are nodes added or
        deleted (`OpcUaServer.drives_changed`)."""
        from gateway.opcua.server import OpcUaServer  # asyncua only when asked for

        settings = self.settings
        parts = (self.router, self.poller, self.tasks, self.events)
        server = OpcUaServer(opcua, settings.buses, settings.drives, *parts)
        self.poller.add_listener(server)
        self.poller.read_max_frequency = True  # the frequencies' EURange
        return server

    def _build_sparkplug(self, mqtt: MqttSettings) -> SparkplugNode | None:
        """The Sparkplug B edge node when `mqtt.sparkplug` asks for it, on the drives the
        running configuration has."""
        if mqtt.sparkplug is None:
            return None
        from gateway.sparkplug.edge_node import SparkplugNode  # protobuf only when asked

        drives = self.settings.drives
        parts = (self.router, self.poller, self.tasks, self.events)
        return SparkplugNode(mqtt, mqtt.sparkplug, drives, *parts)

    async def reload(self, new: GatewaySettings) -> ReloadPlan:
        """Apply a new, valid configuration in place (`gateway.settings.reload`); what changed."""
        poller = self.poller
        profiles = {d.name: d.profile for d in self.settings.drives}
        plan = plan_reload(
            self.settings.source,
            new.source,
            mqtt_running=self.mqtt is not None,
            profiles=profiles,
        )
        await self._check_bridge_alone(plan)  # before anything changes: a refusal keeps it all
        running = self.settings = plan.settings
        for name in plan.removed:
            poller.remove_drive(name)
        closed = self._replace_buses(running, plan.reopened)
        routes = (drive_route(d, self.buses[d.bus]) for d in running.drives)
        self.router.replace_routes(routes, self.buses.values())
        if plan.reopened:
            poller.reroute()
        for drive in plan.added:
            if running.polled(drive):
                poller.add_drive(drive)
        self.tcp.update(running.tcp)
        self.events.update_bounds(running.store)
        logging.getLogger().setLevel(running.log_level)
        await self._reopen(closed)
        await self._reload_metrics(plan)
        await self._reload_mqtt(plan)
        if self.opcua is not None and (plan.added or plan.removed):
            try:
                await self.opcua.drives_changed(plan.removed, plan.added)
            except Exception as exc:  # the rest is applied: say what isn't, never half-fail
                log.exception("reload: the OPC UA server's nodes could not follow the drives")
                plan.restart_needed.append(f"opcua's nodes of the drives changed ({exc})")
        self.settings = plan.settings  # with what could not be applied kept at its running value
        if self.announcer is not None:  # `redundancy:` with MQTT: told to the other box
            self.announcer.reloaded()
        data = {"changed": plan.changed, "restart_needed": plan.restart_needed}
        self.events.record(EventType.CONFIG_RELOADED, data)
        log.warning("config reloaded: %s", plan.summary)
        return plan

    async def _check_bridge_alone(self, plan: ReloadPlan) -> None:
        """Raises BrokerShared when the bridge would start again on a base topic (or broker)
        where another live gateway is: as at start, found before it overwrites that gateway's
        retained state and answers its commands. Our own gateway id there is us: it passes."""
        mqtt = plan.settings.mqtt
        if not plan.restart_bridge or mqtt is None:
            return
        from gateway.mqtt.alone import check_alone
        from gateway.mqtt.topics import Topics

        running = self.mqtt.topics if self.mqtt is not None else None
        await check_alone(mqtt, Topics(mqtt.base_topic), running)

    async def _reload_mqtt(self, plan: ReloadPlan) -> None:
        """The bridge, started again with the running configuration: new settings, the drives
        it serves now (a removed one's topics are no longer subscribed, an added one's are)."""
        old = self.mqtt
        running = plan.settings
        if old is None or not plan.restart_bridge or running.mqtt is None:
            return
        await old.stop()
        self.poller.remove_listener(old)
        old_node, node = self.sparkplug, self._build_sparkplug(running.mqtt)
        if node is not None and old_node is not None:
            node.continue_from(old_node)
        self.sparkplug, self.mqtt = node, self._build_mqtt(running.mqtt, node)
        if self.console is not None:
            self.console.bridge_replaced(self.mqtt)
        await self.mqtt.start(checked=True)  # by `_check_bridge_alone`, before the reload began

    async def _reload_metrics(self, plan: ReloadPlan) -> None:
        metrics = self.metrics
        if metrics is None:
            return
        if plan.added or plan.removed:
            metrics.drives_changed()
        wanted = plan.settings.metrics
        if wanted is None or wanted == metrics.settings:
            return
        try:
            await metrics.rebind(wanted)
        except CannotListen as exc:
            plan.metrics_not_moved(str(exc))

    def _replace_buses(self, running: GatewaySettings, names: list[str]) -> dict[str, Bus]:
        """Close the buses `names` (their queued requests answered 0BH) and put new ones, with
        the settings of `running`, in their place; the buses closed, by name.

        The new buses are in `self.buses` (the one mapping the console and metrics read) and
        take the old ones' listeners at once: requests routed to them wait in their queues
        until `_reopen` runs them.
        """
        closed: dict[str, Bus] = {}
        settings = {b.name: b for b in running.buses}
        for name in names:
            old = self.buses[name]
            old.close("is reopened with new settings")
            new = Bus(settings[name])
            new.take_listeners(old)
            new.tap = old.tap  # a traffic monitor watching the line goes on watching it
            if self.redundancy is not None:  # active (a standby skips reloads): watched too
                self.redundancy.watch(new)
            self.buses[name] = new
            closed[name] = old
        return closed

    async def _reopen(self, closed: dict[str, Bus]) -> None:
        """Let each closed bus finish the transaction on its wire and close its port, then run
        its successor, which opens the port with the new settings."""
        old_tasks = [self._bus_tasks.pop(name) for name in closed]
        if old_tasks:
            await asyncio.wait(old_tasks, timeout=SHUTDOWN_BUDGET_S)
        for task in old_tasks:
            if not task.done():
                await cancel_and_wait(task, SHUTDOWN_BUDGET_S)
        for name in closed:
            bus = self.buses[name]
            if self.phase is not Phase.READY or self._group is None:
                bus.close()  # shutting down meanwhile: nothing will serve it
                continue
            self._bus_tasks[name] = self._group.create_task(bus.run(), name=f"bus:{name}")
        await asyncio.gather(*(self.buses[name].wait_open(2.0) for name in closed))
        for name in closed:
            bus = self.buses[name]
            if bus.state is BusState.OPEN:
                log.info("bus %s: reopened with new settings", name)
            else:
                log.warning("bus %s: port %s not open yet; retrying", name, bus.line.settings.port)

    @property
    def cache(self) -> RegisterCache:
        return self.router.cache

    def _build_console(self, console: ConsoleSettings) -> ConsoleFeature:
        """The console reads the poller's state and sends through the router, with Modbus-TCP's
        write policy; it starts after the poller and stops before it."""
        from gateway.console.events import ConsoleEventsRecorded
        from gateway.console.feature import ConsoleFeature  # aiohttp only when asked for

        return ConsoleFeature(
            console,
            self.settings.buses,
            self.settings.drives,
            self.buses,
            self.router,
            self.poller,
            self.tasks,
            read_only=self.settings.tcp.read_only,
            access=self.tcp.access,
            events=ConsoleEventsRecorded(self.events),
            tcp=self.tcp,
            mqtt=self.mqtt,
            opcua=self.opcua,
            configuration=lambda: self.settings.shown_configuration(),
            history_source=self.events,
        )

    def _drive_of(self, unit_id: int) -> str | None:
        try:
            return self.router.route(unit_id).drive
        except GatewayPathUnavailable:
            return None

    @property
    def serving(self) -> bool:
        """This gateway sends to its drives: always, unless it is a standby (`redundancy`)."""
        return self.redundancy is None or self.redundancy.serving

    async def run(
        self,
        stop: asyncio.Event,
        on_ready: Callable[[], None] | None = None,
        alongside: Mapping[str, Coroutine[Any, Any, None]] | None = None,
    ) -> None:
        """Start up, serve until `stop` is set, shut down. `alongside`: the service's own
        work by task name (the SIGHUP listener, the systemd watchdog), run in the TaskGroup
        like every feature's from the start, and cancelled once the features have stopped."""
        async with asyncio.TaskGroup() as tasks:
            self.tasks.bind(tasks)
            self._group = tasks
            self._bus_tasks = {
                name: tasks.create_task(bus.run(), name=f"bus:{name}")
                for name, bus in self.buses.items()
                if self.redundancy is None  # else the buses run once this gateway is active
            }
            beside = [self.tasks.start(name, work) for name, work in (alongside or {}).items()]
            try:
                await self._startup()
                if self.redundancy is not None:
                    beside.append(self.tasks.start("redundancy", self.redundancy.run()))
                if self.announcer is not None:
                    beside.append(self.tasks.start("redundancy:mqtt", self.announcer.run()))
                self.phase = Phase.READY
                if on_ready is not None:
                    on_ready()
                await stop.wait()
            finally:
                if self.redundancy is not None:  # no role change while the service stops
                    await asyncio.gather(*(cancel_and_wait(t, FEATURE_STOP_S) for t in beside))
                await self._shutdown()
                for task in self._bus_tasks.values():
                    task.cancel()
                running = [task for task in beside if not task.done()]
                await asyncio.gather(*(cancel_and_wait(t, FEATURE_STOP_S) for t in running))
                await self.tasks.stop_left_over(SHUTDOWN_BUDGET_S)
                self.tasks.bind(None)
                self._group = None

    async def _startup(self) -> None:
        # A port that isn't there yet must not keep SCADA from connecting: the bus keeps trying
        # and answers 0x0B meanwhile. Give ports a moment so the first requests find them open.
        if self.redundancy is None:
            await asyncio.gather(*(bus.wait_open(2.0) for bus in self.buses.values()))
        for name, bus in self.buses.items():
            if not bus.line.is_open and self.redundancy is None:
                log.warning("bus %s: port %s not open yet; retrying", name, bus.line.settings.port)
        await self.tcp.start()
        for feature in self.features:
            if feature not in self.handover.waiting:
                await feature.start()

    async def _shutdown(self) -> None:
        self.phase = Phase.STOPPING
        log.info("shutting down")
        self.tcp.stop_accepting()
        for bus in self.buses.values():
            bus.close()
        await asyncio.gather(*(bus.wait_idle(SHUTDOWN_BUDGET_S) for bus in self.buses.values()))
        for feature in reversed(self.features):
            if feature in self.handover.waiting:
                continue  # never started: a standby's poller and bridge (`LineHandover`)
            # Its own task, so a stop that hangs (or swallows its cancellation, Python 3.11's
            # wait_for) can be cut off without holding up the rest of the shutdown.
            name = type(feature).__name__
            stopping = asyncio.create_task(feature.stop(), name=f"stop:{name}")
            done, _ = await asyncio.wait({stopping}, timeout=FEATURE_STOP_S)
            if not done:
                log.error("%s did not stop within %.1f s; cut off", name, FEATURE_STOP_S)
                await cancel_and_wait(stopping, FEATURE_STOP_S)
            elif not stopping.cancelled() and stopping.exception() is not None:
                log.error("%s failed to stop: %r", name, stopping.exception())
        await self.tcp.stop(grace_s=0.2)


class TcpRequests:
    """What Modbus-TCP clients ask goes to the router (`RequestRoute`): every SCADA write
    tallied for the audit (`WriteTally`), answered or refused. Reads that are one transaction
    go to the router's `submit` at once (no task); the router says False to anything else, so
    there is no write to tally there. A standby gateway (`redundancy:`) answers every request
    0AH, saying why (`StandbyRefusal`): SCADA's requests go to the active one."""

    def __init__(self, router: Router, writes: WriteTally) -> None:
        self._router = router
        self._writes = writes
        self.submit = router.submit
        self.serving: Callable[[], bool] | None = None
        """Set with `redundancy:`: False while this gateway is not the line's master."""

    def refuse_unless_serving(self, serving: Callable[[], bool]) -> None:
        """`redundancy:`: requests pass only while `serving` says so (one call more each)."""
        self.serving = serving
        router_submit = self._router.submit

        def submit(unit_id: int, pdu: bytes, client: str, waiter: Waiter) -> bool:
            # False: `execute` takes it, and refuses it there with the reason.
            return serving() and router_submit(unit_id, pdu, client, waiter)

        self.submit = submit

    async def execute(self, unit_id: int, pdu: bytes, client: str) -> bytes | None:
        serving = self.serving
        if serving is not None and not serving():
            self._writes.count(client, unit_id, pdu, refused=True)
            raise StandbyRefusal("standby gateway: the active gateway serves the drives")
        try:
            reply = await self._router.execute(unit_id, pdu, client=client)
        except GatewayError:
            self._writes.count(client, unit_id, pdu, refused=True)
            raise
        refused = reply is not None and is_exception(reply)
        self._writes.count(client, unit_id, pdu, refused=refused)
        return reply


class LineHandover:
    """The application's side of a role change (`gateway.redundancy.LineOwner`): what taking
    and leaving the lines means for its parts. Without `redundancy:` it does nothing.

    Taking: fresh buses (a closed bus stays closed: a standby's refuse every request), each
    watched before it opens its port (`Redundancy`'s hook), routed and run; then the poller
    and the MQTT bridge start, and the OPC UA server beside (its start is slow). Leaving: the
    buses close (queued requests answered, the transaction on a wire finished unless its write
    gate closed), their tasks end, their ports close (the listeners open them next); the
    poller stops, the OPC UA server too, and the bridge, replaced by a new one (unstarted)
    for the next takeover: its session takes over the old one's (the two boxes have one
    gateway id and client id), so no check for another live gateway is made."""

    def __init__(self, app: Application) -> None:
        self.app = app
        self.waiting: list[Feature] = []
        """The parts that run only while this gateway is active, while it is not."""
        self.told_birth: ToldBirth | None = None
        """With MQTT: the bdSeq the other box's Sparkplug node was last born with."""
        self._opcua_start: asyncio.Task[None] | None = None
        """OPC UA's start at a takeover, beside the role: its address space (and, the first
        time, its certificate) takes seconds, which SCADA's Modbus-TCP must not wait for."""

    def build_redundancy(self) -> Redundancy:
        from gateway.redundancy import Redundancy

        app = self.app
        settings = app.settings
        assert settings.redundancy is not None
        for bus in app.buses.values():
            bus.close("is not served by this gateway: it is the standby")
        app.requests.refuse_unless_serving(lambda: app.serving)
        # OPC UA stays off on a standby (clients get "connection refused": not here) and
        # builds its address space at takeover: a standby's would show values nobody polls.
        self.waiting = [part for part in (app.poller, app.mqtt, app.opcua) if part is not None]
        lines = [bus.line for bus in settings.buses]
        redundancy = Redundancy(settings.redundancy, lines, self, app.events)
        if settings.mqtt is not None:
            from gateway.mqtt.role import RoleAnnouncer
            from gateway.mqtt.told import ToldBirth, ToldFaults
            from gateway.redundancy.peer_config import PeerConfig

            box, base = settings.redundancy.box, settings.mqtt.base_topic
            told = ToldFaults(base, (d.name for d in settings.drives))
            self.told_birth = ToldBirth(base, box)
            peer = redundancy.peer_config = PeerConfig(
                lambda: app.settings.redundancy.shared_digests if app.settings.redundancy else {},
                app.events,
            )
            announced, followed = self._announced(redundancy), (told, self.told_birth)
            app.announcer = RoleAnnouncer(settings.mqtt, box, announced, followed, peer)
            app.announcer.hand_events(app.events, lambda: not redundancy.serving)
            redundancy.listeners.append(app.announcer.changed)
            app.poller.open_faults = self._told_first(told)
        if app.console is not None:
            app.console.redundancy = redundancy.status
        return redundancy

    def _told_first(self, told: ToldFaults) -> Callable[[], Awaitable[Mapping[str, int]]]:
        """The fault memory a takeover's first polls compare with: what the consumers were told
        on MQTT (the old active's words, heard while standby), over this box's own store (its
        own last run, stale once the other box has been active)."""
        store = self.app.events

        async def open_faults() -> Mapping[str, int]:
            return {**(await store.open_faults()), **told.faults}

        return open_faults

    def _announced(self, redundancy: Redundancy) -> Callable[[], dict[str, Any]]:
        """What the box's role topic says: the role's status and the health's one word; an
        active box's, the bdSeq its Sparkplug node was last born with."""
        from gateway.mqtt.told import BD_SEQ_KEY

        app = self.app

        def status() -> dict[str, Any]:
            routes = [(r.drive, r.bus.name, r.address) for r in app.router.routes]
            role = redundancy.status()
            tcp = len(app.tcp.stats.active)
            health = health_report(app.phase, app.buses, routes, tcp, 0.0, None, role)
            node = app.sparkplug
            if node is not None and role["role"] == "active" and node.bd_seq.value >= 0:
                role[BD_SEQ_KEY] = node.bd_seq.value  # the other box's node counts on from it
            return {**role, "health": health["status"]}

        return status

    async def take_line(self, hook: Callable[[Bus], None]) -> None:
        app = self.app
        group = app._group
        assert group is not None  # the redundancy task runs in the service's TaskGroup
        running = app.settings
        settings = {b.name: b for b in running.buses}
        fresh: dict[str, Bus] = {}
        for name, old in app.buses.items():
            bus = Bus(settings[name])
            bus.take_listeners(old)
            bus.tap = old.tap
            hook(bus)
            fresh[name] = bus
        app.buses.update(fresh)
        app.router.replace_routes(
            (drive_route(d, app.buses[d.bus]) for d in running.drives), app.buses.values()
        )
        app.poller.reroute()
        app.poller.forget_readings()  # polled before this box last left the line: stale
        for name, bus in fresh.items():
            app._bus_tasks[name] = group.create_task(bus.run(), name=f"bus:{name}")
        await asyncio.gather(*(bus.wait_open(2.0) for bus in fresh.values()))
        node, told = app.sparkplug, self.told_birth
        if node is not None and told is not None:
            if told.bd_seq is not None:
                node.bd_seq.follow_on(told.bd_seq)
            if app.announcer is not None:
                node.born.append(app.announcer.changed)  # the bdSeq in the role announcement
        if app.mqtt is not None and running.redundancy is not None:
            app.mqtt.publisher.box = running.redundancy.box  # the events say which box's
        waiting, self.waiting = self.waiting, []
        for part in waiting:
            if part is app.mqtt and app.mqtt is not None:
                await app.mqtt.start(checked=True)
            elif part is app.opcua and app.opcua is not None:
                self._opcua_start = app.tasks.start("redundancy:opcua", app.opcua.start())
            else:
                await part.start()

    async def leave_line(self, reason: str) -> None:
        app = self.app
        for bus in app.buses.values():
            bus.close(f"stopped: {reason}")
        tasks = list(app._bus_tasks.values())
        app._bus_tasks = {}
        if tasks:
            await asyncio.wait(tasks, timeout=SHUTDOWN_BUDGET_S)
        for task in tasks:
            if not task.done():
                await cancel_and_wait(task, SHUTDOWN_BUDGET_S)
        await app.poller.stop()
        waiting: list[Feature] = [app.poller]
        old = app.mqtt
        if old is not None and app.settings.mqtt is not None:
            await old.stop()
            app.poller.remove_listener(old)
            app.sparkplug = app._build_sparkplug(app.settings.mqtt)
            app.mqtt = app._build_mqtt(app.settings.mqtt, app.sparkplug)
            if app.console is not None:
                app.console.bridge_replaced(app.mqtt)
            waiting.append(app.mqtt)
        if app.opcua is not None:  # a new asyncua server at each start: started again later
            starting, self._opcua_start = self._opcua_start, None
            if starting is not None:
                await cancel_and_wait(starting, SHUTDOWN_BUDGET_S)
            await app.opcua.stop()
            waiting.append(app.opcua)
        self.waiting = waiting
