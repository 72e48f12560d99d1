"""The console as one feature of the application: `start()` and `stop()`, its parts passed in.

Everything it needs from the gateway comes through the constructor (the buses, the router, the
Modbus-TCP server's policy, the poller, an event store), so re-wiring the application touches
only the few lines that build it. It runs on the gateway's own event loop: aiohttp's server,
the bus sampler and every stream are coroutines there, and nothing of it ever waits on a bus.
"""

from __future__ import annotations

import asyncio
import logging
import ssl
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from aiohttp import web

from gateway.bus import Bus, BusSettings
from gateway.console import configuration, history
from gateway.console.auth import Users
from gateway.console.bad_requests import BadRequests
from gateway.console.config_editor import ConfigEditor
from gateway.console.context import Console
from gateway.console.deadlines import KEEP_ALIVE_S, DeadlinedSite, RequestDeadlines
from gateway.console.diagnostics import MqttSession, OpcUaSessions, TcpClients
from gateway.console.events import EventStore, MemoryEventStore
from gateway.console.live import LiveState
from gateway.console.log_tail import LogTail
from gateway.console.operations import DriveOperations, Policy
from gateway.console.traffic import DriveLabel, TrafficMonitor
from gateway.console.web import build_app
from gateway.listen import cannot_listen
from gateway.poller import Poller
from gateway.routing import Router
from gateway.settings import ConsoleSettings, DriveSettings
from gateway.tasks import ServiceTasks, cancel_and_wait
from gateway.tcp.access import AccessPolicy

log = logging.getLogger(__name__)

SAMPLE_PERIOD_S = 1.0
SHUTDOWN_S = 0.2
"""Open streams are told to end first; then aiohttp gets this long before it cuts them."""


class ConsoleFeature:
    def __init__(
        self,
        settings: ConsoleSettings,
        lines: Sequence[BusSettings],
        drives: Sequence[DriveSettings],
        buses: Mapping[str, Bus],
        router: Router,
        poller: Poller | None,
        tasks: ServiceTasks,
        *,
        read_only: bool,
        access: AccessPolicy | None,
        events: EventStore | None = None,
        tcp: TcpClients | None = None,
        mqtt: MqttSession | None = None,
        opcua: OpcUaSessions | None = None,
        configuration: Callable[[], dict[str, Any]] | None = None,
        history_source: history.HistorySource | None = None,
    ) -> None:
        self.settings = settings
        self.lines = lines
        self.drives = drives
        self.buses = buses
        self.router = router
        self.poller = poller
        self.tasks = tasks
        self.read_only = read_only
        self.access = access
        self.events: EventStore = events if events is not None else MemoryEventStore()
        self.tcp = tcp
        self.mqtt = mqtt
        self.opcua = opcua  # what the diagnostics page reads of the Modbus-TCP, MQTT, OPC UA
        self.configuration = configuration
        """The running configuration, secrets masked, as of now (after the last reload)."""
        self.history_source = history_source
        """The store's history of polled values (None: the live 15 minutes only)."""
        self.config_editor: ConfigEditor | None = None
        """Editing the configuration file (`invt-gateway run` sets it: it knows the file)."""
        self.redundancy: Callable[[], dict[str, Any]] | None = None
        """With `redundancy:`, this box's role as `role status` says it: the overview's banner."""
        self.console: Console | None = None
        self._runner: web.AppRunner | None = None
        self._site: DeadlinedSite | None = None
        self.bad_requests = BadRequests()
        """Requests refused for their content (414, 413, 400), counted by status."""
        self.deadlines = RequestDeadlines(settings.request_timeout_s, self.bad_requests)
        self._sampler: asyncio.Task[None] | None = None
        self._live: LiveState | None = None
        self.log_tail = LogTail()  # the log's recent lines for the diagnostics page

    @property
    def port(self) -> int:
        assert self._runner is not None, "start() first"
        return int(self._runner.addresses[0][1])

    @property
    def url(self) -> str:
        scheme = "https" if self.settings.cert_file else "http"
        return f"{scheme}://{self.settings.host}:{self.port}/"

    async def start(self) -> None:
        live = LiveState(self.buses, self.lines, self.drives, self.poller, self.events)
        live.redundancy = self.redundancy
        if self.poller is not None:
            self.poller.add_listener(live)
        for bus in self.buses.values():
            bus.add_request_observer(live.request_done)
        self._live = live
        self.console = self._console(live)
        self.console.traffic.record_always()
        self.log_tail.attach()
        app = build_app(self.console, self.bad_requests)
        history.add_routes(app, self.history_source)
        configuration.add_routes(app, self.config_editor)
        await self._listen(app)
        live.sample_buses()
        # In the service's TaskGroup: a bug here stops the service, saying so, rather than
        # freezing the charts without a word.
        self._sampler = self.tasks.start("console:sampler", self._sample(live))
        log.info("console on %s", self.url)

    def bridge_replaced(self, mqtt: MqttSession | None) -> None:
        """The application built its MQTT bridge again (a reload, a takeover): the diagnostics
        page reads the new one's session, not the stopped one's."""
        self.mqtt = mqtt
        if self.console is not None:
            self.console.mqtt = mqtt

    def _console(self, live: LiveState) -> Console:
        """The parts the handlers use: who may log in, the drives' operations under the access
        rules, the line monitor, the events and the diagnostics' sources."""
        settings = self.settings
        drives = self.drives
        labels = {(d.bus, d.address): DriveLabel(d.name, d.unit_id, d.profile) for d in drives}
        policy = Policy(self.read_only, self.access, settings.commands_enabled)
        operations = DriveOperations(
            {d.name: d for d in drives}, self.router, policy, self.poller, self.events
        )
        return Console(
            users=Users(settings.users),
            anonymous_view=settings.anonymous_view,
            commands_enabled=settings.commands_enabled,
            secure_cookies=settings.cert_file is not None,
            live=live,
            operations=operations,
            traffic=TrafficMonitor(self.buses, labels),
            events=self.events,
            tcp=self.tcp,
            mqtt=self.mqtt,
            opcua=self.opcua,
            log=self.log_tail,
            configuration=self.configuration,
        )

    async def _listen(self, app: web.Application) -> None:
        """Serve `app` on console.host/port (HTTPS with a certificate), each request within its
        deadlines; `CannotListen` naming the keys when the address can't be had."""
        settings = self.settings
        self._runner = web.AppRunner(
            app,
            access_log=None,
            logger=self.bad_requests.server_log(),  # its parser's refusals: no traceback each
            shutdown_timeout=SHUTDOWN_S,
            keepalive_timeout=KEEP_ALIVE_S,
        )
        await self._runner.setup()
        site = DeadlinedSite(
            self._runner, settings.host, settings.port, self.deadlines, self._ssl_context()
        )
        try:
            await site.start()
        except OSError as exc:
            self.log_tail.detach()
            await self._runner.cleanup()
            raise cannot_listen(
                "the console", settings.host, settings.port, "console.host/port", exc
            ) from exc
        self._site = site

    async def stop(self) -> None:
        if self.console is not None:
            self.console.closing.set()  # every stream ends its loop
            self.console.traffic.close()
        if self._live is not None:
            for bus in self.buses.values():
                bus.remove_request_observer(self._live.request_done)
        if self._sampler is not None:
            await cancel_and_wait(self._sampler, 0.2)
        if self._runner is not None:
            await self._runner.cleanup()
        self.log_tail.detach()

    def _ssl_context(self) -> ssl.SSLContext | None:
        settings = self.settings
        if settings.cert_file is None or settings.key_file is None:
            return None
        context = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
        context.minimum_version = ssl.TLSVersion.TLSv1_2
        context.load_cert_chain(settings.cert_file, settings.key_file)
        return context

    async def _sample(self, live: LiveState) -> None:
        while True:
            await asyncio.sleep(SAMPLE_PERIOD_S)
            live.sample_buses()
