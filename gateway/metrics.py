"""Prometheus metrics and the health endpoint, on one HTTP port (`metrics: {host, port}`).

Each part owns its metric families, a prometheus_client `Collector` over its own counters read
at scrape time (`gateway.metric_families` lists them): this module registers them, adds the
gateway's own (its build, ready) and the process's, and serves them. It reads no part's
counters itself.

Endpoints: /metrics (Prometheus text format), /health and /health/ready (200 when ready, else
503), /health/live (200 whenever the event loop answers). The health body is JSON.
"""

from __future__ import annotations

import json
import logging
import platform
import time
from collections.abc import Callable, Iterable, Mapping
from http import HTTPStatus
from typing import TYPE_CHECKING, Generic, Protocol, TypeVar

from prometheus_client import (
    CONTENT_TYPE_LATEST,
    CollectorRegistry,
    ProcessCollector,
)
from prometheus_client.core import GaugeMetricFamily, InfoMetricFamily
from prometheus_client.metrics_core import Metric
from prometheus_client.registry import Collector

from gateway import ENGINE_ROOM, __version__
from gateway.bus import Bus
from gateway.bus.metrics import BusMetrics, DriveLabels
from gateway.bus.request_metrics import RequestMetrics
from gateway.compiled import COMPILED
from gateway.errors import CannotListen
from gateway.event_loop import running_loop_name
from gateway.exposition import exposition
from gateway.health import Phase, health_report
from gateway.http_endpoint import HttpEndpoint, Response
from gateway.metric_families import PREFIX
from gateway.routing import Router
from gateway.settings import GatewaySettings, MetricsSettings
from gateway.store import EventStore
from gateway.store.metrics import StoreMetrics
from gateway.tcp.metrics import TcpMetrics
from gateway.tcp.server import ModbusTcpServer

if TYPE_CHECKING:
    from gateway.console.feature import ConsoleFeature
    from gateway.mqtt import MqttBridge
    from gateway.redundancy import Redundancy

log = logging.getLogger(__name__)
T = TypeVar("T")


class Service(Protocol):
    """What metrics and health read from the application."""

    @property
    def settings(self) -> GatewaySettings: ...

    @property
    def buses(self) -> Mapping[str, Bus]: ...

    @property
    def router(self) -> Router: ...

    @property
    def tcp(self) -> ModbusTcpServer: ...

    @property
    def phase(self) -> Phase: ...

    @property
    def events(self) -> EventStore: ...

    @property
    def mqtt(self) -> MqttBridge | None:
        """None: MQTT is not configured. A reload may replace the bridge."""

    @property
    def console(self) -> ConsoleFeature | None:
        """None: the console is not configured."""

    @property
    def redundancy(self) -> Redundancy | None:
        """None: no `redundancy:`, this gateway is its lines' only master."""


def drive_labels(service: Service) -> list[DriveLabels]:
    models = {drive.name: drive.model for drive in service.settings.drives}
    return [
        DriveLabels(route.drive, route.bus.name, route.address, route.unit_id, models[route.drive])
        for route in service.router.routes
    ]


class GatewayMetrics(Collector):
    """The gateway's own: its build and whether it is ready."""

    def __init__(self, service: Service) -> None:
        self.service = service

    def collect(self) -> Iterable[GaugeMetricFamily | InfoMetricFamily]:
        info = InfoMetricFamily(f"{PREFIX}_build", "Version and id of this gateway")
        labels = {
            "version": __version__,
            "gateway_id": self.service.settings.gateway_id,
            "event_loop": running_loop_name(),
            "python": platform.python_version(),
        }
        info.add_metric([], labels)
        yield info
        compiled = GaugeMetricFamily(
            f"{PREFIX}_engine_room_compiled",
            "1 when the modules every transaction crosses run compiled by mypyc, 0 as Python",
        )
        compiled.add_metric([], 1.0 if ENGINE_ROOM == COMPILED else 0.0)
        yield compiled
        ready = GaugeMetricFamily(f"{PREFIX}_ready", "1 once started, 0 while starting/stopping")
        ready.add_metric([], 1.0 if self.service.phase is Phase.READY else 0.0)
        yield ready


class OfTheCurrent(Collector, Generic[T]):
    """The families of a part a reload may replace (the MQTT bridge): the current one's, read
    off the application at each scrape; none while there is none."""

    def __init__(self, current: Callable[[], T | None], families: Callable[[T], Collector]) -> None:
        self._current = current
        self._families = families

    def collect(self) -> Iterable[Metric]:
        part = self._current()
        return () if part is None else self._families(part).collect()


async def _scrape(registry: CollectorRegistry) -> Response:
    return Response(200, CONTENT_TYPE_LATEST, await exposition(registry))


class MetricsFeature:
    """Serves /metrics and /health while the gateway runs; a feature of the application."""

    def __init__(self, service: Service, settings: MetricsSettings) -> None:
        self.service = service
        self.settings = settings
        self.endpoint: HttpEndpoint | None = None
        self._requests: RequestMetrics | None = None
        self._buses: BusMetrics | None = None
        self._registry: CollectorRegistry | None = None
        self._started_at = time.monotonic()

    @property
    def port(self) -> int:
        assert self.endpoint is not None, "start() first"
        return self.endpoint.port

    async def start(self) -> None:
        registry = CollectorRegistry(auto_describe=True)
        drives = drive_labels(self.service)
        self._requests = RequestMetrics(drives)
        self._buses = BusMetrics(self.service.buses, drives)
        for part in (self._requests, GatewayMetrics(self.service), self._buses, *self._parts()):
            registry.register(part)
        ProcessCollector(registry=registry)
        self._registry = registry
        for bus in self.service.buses.values():
            bus.add_request_observer(self._requests.observe)
        self.endpoint = self._endpoint(self.settings)
        await self.endpoint.start()
        log.info("metrics and health on http://%s:%d/", self.settings.host, self.endpoint.port)

    def _parts(self) -> Iterable[Collector]:
        """The families of the other parts, each its own: the Modbus-TCP server's, the MQTT
        bridge's and the console's when they run (their libraries loaded only then), the
        store's."""
        service = self.service
        yield TcpMetrics(service.tcp)
        if service.mqtt is not None:
            from gateway.mqtt.metrics import MqttMetrics

            yield OfTheCurrent(lambda: service.mqtt, MqttMetrics)
        if service.console is not None:
            from gateway.console.metrics import ConsoleMetrics

            yield ConsoleMetrics(service.console)
        yield StoreMetrics(service.events)
        from gateway.redundancy.metrics import RedundancyMetrics

        yield RedundancyMetrics(lambda: service.redundancy)

    def _endpoint(self, settings: MetricsSettings) -> HttpEndpoint:
        registry = self._registry
        assert registry is not None
        return HttpEndpoint(
            settings.host,
            settings.port,
            {
                "/metrics": lambda: _scrape(registry),
                "/health": self._health,
                "/health/ready": self._health,
                "/health/live": self._live,
            },
        )

    # -- a reload ------------------------------------------------------------------------------

    def drives_changed(self) -> None:
        """Drives added or removed: labelled by their names from the next request and scrape."""
        drives = drive_labels(self.service)
        if self._requests is not None and self._buses is not None:
            self._requests.relabel(drives)
            self._buses.relabel(drives)

    async def rebind(self, settings: MetricsSettings) -> None:
        """Listen on a new host and port; the counters go on. Raises CannotListen (and keeps
        listening where it did) when the new address can't be had."""
        old = self.endpoint
        new = self._endpoint(settings)
        try:
            await new.start()
        except CannotListen:
            # The old socket may hold the port (the same port, another host): free it, try again.
            if old is None:
                raise
            await old.stop()
            try:
                await new.start()
            except CannotListen:
                await old.start()
                raise
        else:
            if old is not None:
                await old.stop()
        self.endpoint, self.settings = new, settings
        log.info("metrics and health now on http://%s:%d/", settings.host, new.port)

    async def stop(self) -> None:
        if self._requests is not None:
            for bus in self.service.buses.values():
                bus.remove_request_observer(self._requests.observe)
        if self.endpoint is not None:
            await self.endpoint.stop()

    def _report(self) -> dict[str, object]:
        service = self.service
        drives = [(route.drive, route.bus.name, route.address) for route in service.router.routes]
        report = health_report(
            service.phase,
            service.buses,
            drives,
            len(service.tcp.stats.active),
            self._started_at,
            service.events.status(),
            None if service.redundancy is None else service.redundancy.status(),
        )
        return {"gateway_id": service.settings.gateway_id, "version": __version__, **report}

    def _health(self) -> Response:
        report = self._report()
        status = HTTPStatus.OK if report["ready"] else HTTPStatus.SERVICE_UNAVAILABLE
        return Response(status, "application/json", json.dumps(report).encode() + b"\n")

    def _live(self) -> Response:
        return Response(HTTPStatus.OK, "application/json", json.dumps(self._report()).encode())
