"""The application: wires the configured parts together and runs their lifecycle.

    startup   buses open their ports (in the background, with backoff), the TCP server listens,
              features (poller, MQTT bridge, metrics) start, then "ready" is reported; every
              background task (buses, poller, MQTT) runs in one TaskGroup: one that dies of a
              bug stops the service (`BusFailed`, `FeatureFailed`: exit code 1)
    serve     until the stop event is set (SIGTERM / SIGINT)
    shutdown  stop accepting; queued requests are answered 0x0B; the transaction on the wire
              finishes; features stop (MQTT publishes offline); within 2 s in all

It does nothing itself but wiring: each part gets its dependencies passed in.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable
from typing import TYPE_CHECKING, Protocol

from gateway.bus import Bus, BusSettings, BusState
from gateway.bus.direction import DirectionControl, DirectionMode
from gateway.bus.line import LineSettings
from gateway.bus.line_share import LineShares
from gateway.bus.queue import Waiter
from gateway.config import (
    AccessRuleConfig,
    BusConfig,
    DriveConfig,
    GatewayConfig,
    ModbusTcpConfig,
    Rs485Config,
)
from gateway.errors import CannotListen, GatewayError, GatewayPathUnavailable
from gateway.health import Phase
from gateway.modbus.functions import is_exception
from gateway.modbus.timing import CharacterFormat
from gateway.poller import Poller
from gateway.profile.ram_writes import ram_write_address
from gateway.reload import ReloadPlan
from gateway.reload import plan as plan_reload
from gateway.routing import RegisterCache, Route, Router
from gateway.store import EventStore, EventType
from gateway.store.modbus_writes import WriteTally
from gateway.tasks import ServiceTasks, cancel_and_wait
from gateway.tcp import ModbusTcpServer, TcpSettings
from gateway.tcp.access import AccessRule, merge_spans
from gateway.tcp.server import TlsListener

if TYPE_CHECKING:
    from gateway.metrics import MetricsFeature

log = logging.getLogger(__name__)

EVENTS_WAITING = 1000
"""Events waiting in memory for the store's disk (without MQTT, whose queue_size says it)."""
SHUTDOWN_BUDGET_S = 1.5
FEATURE_STOP_S = 0.5
"""Time for the transaction on the wire and the answers in flight, inside the 2 s promise."""


class Feature(Protocol):
    """A part with a lifecycle; its constructor only stores its dependencies."""

    async def start(self) -> None: ...

    async def stop(self) -> None: ...


def bus_settings(config: BusConfig) -> BusSettings:
    char_format = CharacterFormat(config.baudrate, config.parity, config.stopbits, config.bytesize)
    gap_s = char_format.t35_s if config.gap_ms is None else config.gap_ms / 1000
    return BusSettings(
        name=config.name,
        line=LineSettings(
            port=config.port,
            char_format=char_format,
            gap_s=gap_s,
            char_timeout_s=config.char_timeout_ms / 1000,
            drain_s=config.drain_ms / 1000,
            turnaround_s=config.turnaround_ms / 1000,
            echo=config.echo,
            direction=direction_control(config.rs485),
            name=config.name,
        ),
        timeout_s=config.timeout_ms / 1000,
        retries=config.retries,
        queue_size=config.queue_size,
        offline_after=config.offline_after,
        probe_max_s=config.probe_max_s,
        shares=LineShares(config.write_share, config.broadcast_share),
    )


def direction_control(config: Rs485Config | None) -> DirectionControl | None:
    if config is None:
        return None
    return DirectionControl(
        mode=DirectionMode(config.mode),
        rts_level_for_tx=config.rts_level_for_tx == "high",
        delay_before_tx_s=config.delay_before_tx_ms / 1000,
        delay_after_tx_s=config.delay_after_tx_ms / 1000,
    )


def drive_route(drive: DriveConfig, bus: Bus) -> Route:
    profile = drive.profile()
    split = profile.is_invt if drive.split is None else drive.split
    return Route(
        unit_id=drive.effective_unit_id,
        drive=drive.name,
        bus=bus,
        address=drive.address,
        timeout_s=None if drive.timeout_ms is None else drive.timeout_ms / 1000,
        retries=drive.retries,
        max_words=profile.max_words if split else None,
        ram_address=ram_write_address
        if drive.ram_writes and profile.ram_writes_supported
        else None,
        cache_max_age_s=None if drive.cache_max_age_ms is None else drive.cache_max_age_ms / 1000,
    )


def access_rule(config: AccessRuleConfig, index: int) -> AccessRule:
    spans = None
    if config.registers is not None:
        spans = merge_spans(span for entry in config.registers for span in entry.spans)
    return AccessRule(
        allow=config.allow,
        unit_ids=None if config.unit_ids is None else frozenset(config.unit_ids),
        functions=None if config.functions is None else frozenset(config.functions),
        spans=spans,
        label=config.name or f"access[{index}]",
        roles=None if config.roles is None else frozenset(config.roles),
    )


def tls_listener(config: ModbusTcpConfig) -> TlsListener | None:
    tls = config.tls
    if not tls.enabled:
        return None
    # The config refuses tls.enabled without the three files.
    return TlsListener(
        host=tls.host or config.host,
        port=tls.port,
        cert_file=tls.cert_file or "",
        key_file=tls.key_file or "",
        ca_file=tls.ca_file or "",
        role_map=dict(tls.role_map),
    )


def tcp_settings(tcp: ModbusTcpConfig) -> TcpSettings:
    return TcpSettings(
        host=tcp.host,
        port=tcp.port,
        max_connections=tcp.max_connections,
        idle_timeout_s=tcp.idle_timeout_s,
        max_requests_per_connection=tcp.max_requests_per_connection,
        broadcast_reply=tcp.broadcast_reply,
        allowed_networks=tcp.allowed_networks,
        read_only=tcp.read_only,
        access=tuple(access_rule(r, i) for i, r in enumerate(tcp.access)),
        first_request_timeout_s=tcp.first_request_timeout_s,
        plain=tcp.plain,
        tls=tls_listener(tcp),
        max_connections_per_client=tcp.max_connections_per_client,
        max_queued_writes_per_client=tcp.max_queued_writes_per_client,
    )


class Application:
    def __init__(self, config: GatewayConfig) -> None:
        self.config = config
        self.buses = {b.name: Bus(bus_settings(b)) for b in config.buses}
        self.router = Router(
            (drive_route(d, self.buses[d.bus]) for d in config.drives), self.buses.values()
        )
        for bus in self.buses.values():
            bus.add_listener(self.router.on_drive_health)
        self.tcp = ModbusTcpServer(
            tcp_settings(config.modbus_tcp), self._handle_tcp, self._submit_tcp
        )
        self.features: list[Feature] = []
        self.tasks = ServiceTasks()
        self._group: asyncio.TaskGroup | None = None
        self._bus_tasks: dict[str, asyncio.Task[None]] = {}
        """Each bus's `run`, by name: a reload that reopens a bus waits for its old one."""
        self.phase = Phase.STARTING
        mqtt = config.mqtt is not None and config.mqtt.enabled
        # Started before the features that record events, stopped after them: none is lost.
        self.events = EventStore(
            config.storage,
            self.tasks,
            forwarding=mqtt,
            max_waiting=config.mqtt.queue_size if config.mqtt is not None else EVENTS_WAITING,
        )
        self.features.append(self.events)
        for bus in self.buses.values():
            bus.add_port_listener(self.events.port_changed)
        self.writes = WriteTally(self.events, self._drive_of, self.tasks)
        self.features.append(self.writes)
        # Without MQTT or the console only the drives that ask for it are polled: polls cost
        # line time, and a pure Modbus-TCP gateway shouldn't spend it unasked.
        polled = [d for d in config.drives if self._polled(d)]
        if polled:
            self._add_poller(polled)
        if mqtt:
            self._add_mqtt(config)
        if config.metrics.enabled:
            from gateway.metrics import MetricsFeature  # prometheus-client only when asked for

            # First to start, last to stop: /health answers while the others come and go.
            self.metrics = MetricsFeature(self)
            self.features.insert(0, self.metrics)
        if config.console.enabled:
            self._add_console(config)

    def _add_poller(self, drives: list[DriveConfig]) -> None:
        """Polls feed the cache, the fault log and (when configured) the MQTT bridge."""
        from gateway.event_log import DriveEventLog

        self.poller = Poller(drives, self.router, self.tasks)
        for bus in self.buses.values():
            bus.add_listener(self.poller.on_drive_health)
        self.poller.add_listener(DriveEventLog())
        self.poller.add_listener(self.events)
        self.features.append(self.poller)

    def _add_mqtt(self, config: GatewayConfig) -> None:
        """The bridge stops before the poller that feeds it (features stop in reverse)."""
        from gateway.mqtt import MqttBridge  # aiomqtt only loaded when MQTT is configured

        self.mqtt = MqttBridge(config, self.router, self.poller, self.tasks, self.events)
        assert config.mqtt is not None
        self.poller.read_max_frequency = config.mqtt.homeassistant_discovery
        self.poller.add_listener(self.mqtt)
        self.features.append(self.mqtt)

    async def reload(self, new: GatewayConfig) -> ReloadPlan:
        """Apply a new, valid configuration in place (see `gateway.reload`); what changed."""
        poller: Poller | None = getattr(self, "poller", None)
        plan = plan_reload(self.config, new, mqtt_running=hasattr(self, "mqtt"))
        running = self.config = plan.running
        if poller is None and any(self._polled(d) for d in plan.added):
            plan.restart_needed.append("polling (no drive was polled at start)")
        for name in plan.removed:
            if poller is not None:
                poller.remove_drive(name)
        closed = self._replace_buses(running, plan.reopened)
        routes = (drive_route(d, self.buses[d.bus]) for d in running.drives)
        self.router.replace_routes(routes, self.buses.values())
        if poller is not None and plan.reopened:
            poller.reroute()
        for drive in plan.added:
            if poller is not None and self._polled(drive):
                poller.add_drive(drive)
        self.tcp.update(tcp_settings(running.modbus_tcp))
        self.events.update_bounds(running.storage)
        logging.getLogger().setLevel(running.logging.level.upper())
        await self._reopen(closed)
        await self._reload_metrics(plan)
        await self._reload_mqtt(plan)
        self.config = plan.running  # with what could not be applied kept at its running value
        data = {"changed": plan.changed, "restart_needed": plan.restart_needed}
        self.events.record(EventType.CONFIG_RELOADED, data)
        log.warning("config reloaded: %s", plan.summary)
        return plan

    async def _reload_mqtt(self, plan: ReloadPlan) -> None:
        """The bridge, started again with the running configuration: new settings, the drives
        it serves now (a removed one's topics are no longer subscribed, an added one's are)."""
        old = getattr(self, "mqtt", None)
        if old is None or not plan.restart_bridge:
            return
        from gateway.mqtt import MqttBridge

        await old.stop()
        self.poller.remove_listener(old)
        new = MqttBridge(plan.running, self.router, self.poller, self.tasks, self.events)
        self.poller.add_listener(new)
        self.features[self.features.index(old)] = new
        self.mqtt = new
        await new.start()

    async def _reload_metrics(self, plan: ReloadPlan) -> None:
        metrics: MetricsFeature | None = getattr(self, "metrics", None)
        if metrics is None:
            return
        if plan.added or plan.removed:
            metrics.drives_changed()
        wanted = plan.running.metrics
        if wanted == metrics.settings:
            return
        try:
            await metrics.rebind(wanted)
        except CannotListen as exc:
            plan.changed.remove("metrics.host/port")
            plan.restart_needed.append(f"metrics.host/port ({exc})")
            plan.running = plan.running.model_copy(update={"metrics": metrics.settings})

    def _replace_buses(self, running: GatewayConfig, names: list[str]) -> dict[str, Bus]:
        """Close the buses `names` (their queued requests answered 0BH) and put new ones, with
        the settings of `running`, in their place; the buses closed, by name.

        The new buses are in `self.buses` (the one mapping the console and metrics read) and
        take the old ones' listeners at once: requests routed to them wait in their queues
        until `_reopen` runs them.
        """
        closed: dict[str, Bus] = {}
        configs = {b.name: b for b in running.buses}
        for name in names:
            old = self.buses[name]
            old.close("is reopened with new settings")
            new = Bus(bus_settings(configs[name]))
            new.take_listeners(old)
            new.tap = old.tap  # a traffic monitor watching the line goes on watching it
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

    def _polled(self, drive: DriveConfig) -> bool:
        mqtt = self.config.mqtt is not None and self.config.mqtt.enabled
        console = self.config.console.enabled
        return mqtt or console or drive.poll is not None or drive.cache_max_age_ms is not None

    @property
    def cache(self) -> RegisterCache:
        return self.router.cache

    def _add_console(self, config: GatewayConfig) -> None:
        """The console reads the poller's state and sends through the router, with Modbus-TCP's
        write policy; it starts after the poller and stops before it."""
        from gateway.console.events import ConsoleEventsRecorded
        from gateway.console.feature import ConsoleFeature  # aiohttp only when asked for

        self.console = ConsoleFeature(
            config,
            self.buses,
            self.router,
            getattr(self, "poller", None),
            read_only=config.modbus_tcp.read_only,
            access=self.tcp.access,
            events=ConsoleEventsRecorded(self.events),
        )
        self.features.append(self.console)

    async def _handle_tcp(self, unit_id: int, pdu: bytes, client: str) -> bytes | None:
        try:
            reply = await self.router.execute(unit_id, pdu, client=client)
        except GatewayError:
            self.writes.count(client, unit_id, pdu, refused=True)
            raise
        self.writes.count(client, unit_id, pdu, refused=reply is not None and is_exception(reply))
        return reply

    def _submit_tcp(self, unit_id: int, pdu: bytes, client: str, waiter: Waiter) -> bool:
        # Reads only (the router says False to anything else): no write to tally here.
        return self.router.submit(unit_id, pdu, client=client, waiter=waiter)

    def _drive_of(self, unit_id: int) -> str | None:
        try:
            return self.router.route(unit_id).drive
        except GatewayPathUnavailable:
            return None

    async def run(self, stop: asyncio.Event, on_ready: Callable[[], None] | None = None) -> None:
        async with asyncio.TaskGroup() as tasks:
            self.tasks.bind(tasks)
            self._group = tasks
            self._bus_tasks = {
                name: tasks.create_task(bus.run(), name=f"bus:{name}")
                for name, bus in self.buses.items()
            }
            try:
                await self._startup()
                self.phase = Phase.READY
                if on_ready is not None:
                    on_ready()
                await stop.wait()
            finally:
                await self._shutdown()
                for task in self._bus_tasks.values():
                    task.cancel()
                self.tasks.bind(None)
                self._group = None

    async def _startup(self) -> None:
        # A port that isn't there yet must not keep SCADA from connecting: the bus keeps trying
        # and answers 0x0B meanwhile. Give ports a moment so the first requests find them open.
        await asyncio.gather(*(bus.wait_open(2.0) for bus in self.buses.values()))
        for name, bus in self.buses.items():
            if not bus.line.is_open:
                log.warning("bus %s: port %s not open yet; retrying", name, bus.line.settings.port)
        await self.tcp.start()
        for feature in self.features:
            await feature.start()

    async def _shutdown(self) -> None:
        self.phase = Phase.STOPPING
        log.info("shutting down")
        self.tcp.stop_accepting()
        for bus in self.buses.values():
            bus.close()
        await asyncio.gather(*(bus.wait_idle(SHUTDOWN_BUDGET_S) for bus in self.buses.values()))
        for feature in reversed(self.features):
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
