"""Prometheus metrics and the health endpoint, on one HTTP port (`metrics: {host, port}`).

Most values are read at scrape time from the counters the parts already keep (`BusStats`,
`DriveStats`, `TcpStats`, the health tracker): nothing is added to the bus's hot path for them.
The buses write those counters on the same event loop the scrape runs on, so a scrape always sees
whole transactions and needs no lock.
Only what has to be seen per request, by who asked and how long it took, comes through the
bus's request observer: a counter by source and function code, and a latency histogram.

Bus utilisation is `rate(invt_gateway_bus_busy_seconds_total[1m])`: the fraction of time the
line was held by a transaction, response timeouts included (a dead drive costs line time too).

Endpoints: /metrics (Prometheus text format), /health and /health/ready (200 when ready, else
503), /health/live (200 whenever the event loop answers). The health body is JSON.
"""

from __future__ import annotations

import json
import logging
import platform
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from http import HTTPStatus
from typing import TYPE_CHECKING, Protocol, TypeVar

from prometheus_client import (
    CONTENT_TYPE_LATEST,
    CollectorRegistry,
    ProcessCollector,
)
from prometheus_client import metrics as prometheus_client_metrics
from prometheus_client.core import (
    CounterMetricFamily,
    GaugeMetricFamily,
    HistogramMetricFamily,
    InfoMetricFamily,
)
from prometheus_client.metrics_core import Metric
from prometheus_client.registry import Collector

from gateway import __version__
from gateway.buckets import Buckets
from gateway.bus import Bus, BusState, RequestDone
from gateway.bus.line import SerialLine
from gateway.errors import CannotListen
from gateway.event_loop import running_loop_name
from gateway.exposition import exposition
from gateway.health import Phase, health_report
from gateway.http_endpoint import HttpEndpoint, Response
from gateway.modbus.functions import FUNCTIONS
from gateway.modbus.request_checks import Reason

if TYPE_CHECKING:
    from gateway.console.feature import ConsoleFeature
    from gateway.mqtt import MqttBridge
from gateway.routing import Router
from gateway.settings import GatewaySettings, MetricsSettings
from gateway.store import EventStore
from gateway.tcp.access import AccessPolicy
from gateway.tcp.server import ModbusTcpServer, TcpStats

log = logging.getLogger(__name__)
K = TypeVar("K")
V = TypeVar("V")

PREFIX = "invt_gateway"
SOURCES = ("tcp", "poll", "mqtt", "probe")
"""Who asked: clients are named "tcp:<peer>", "poll", "mqtt" and "probe" (the bus's own)."""
BROADCAST = "broadcast"
LATENCY_BUCKETS = (0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0)
"""Seconds: one short read at 115200 baud takes ~3 ms, a 16-word read at 9600 ~50 ms, and a
queue behind a dead drive seconds."""


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


@dataclass(frozen=True, slots=True)
class DriveLabels:
    drive: str
    bus: str
    address: int
    unit_id: int
    model: str


def drive_labels(service: Service) -> list[DriveLabels]:
    models = {drive.name: drive.model for drive in service.settings.drives}
    return [
        DriveLabels(route.drive, route.bus.name, route.address, route.unit_id, models[route.drive])
        for route in service.router.routes
    ]


def request_source(client: str) -> str:
    """ "tcp:10.0.0.5:51234" → "tcp"; anything unforeseen → "other" (bounded label values)."""
    head = client.split(":", 1)[0]
    return head if head in SOURCES else "other"


OTHER = "other"


def function_label(function: int) -> str:
    """The codes of the function-code registry by name, any other `other`: a client choosing
    random codes must not grow the metrics by a series per code."""
    return f"{function:02X}" if function in FUNCTIONS else OTHER


def exception_label(code: int) -> str:
    """01H-0BH by name of code; anything else a drive might send, "other"."""
    return f"{code:02X}" if 0x01 <= code <= 0x0B else OTHER


class _Count:
    """One series' count and when it began (Prometheus's `_created`)."""

    __slots__ = ("created", "value")

    def __init__(self) -> None:
        self.value = 0
        self.created = time.time()


class _Latency(Buckets):
    __slots__ = ("created",)

    def __init__(self) -> None:
        super().__init__(LATENCY_BUCKETS)
        self.created = time.time()


class RequestMetrics(Collector):
    """Per request, as the bus reports it: how many, from whom, which function, how fast.

    Counted in plain numbers by the bus's request observer and turned into Prometheus families
    only when scraped (both on the event loop, so no lock): prometheus_client's counters and
    histograms take a lock per increment and per observation, which cost 9 % of a transaction's
    CPU with no wire delay (callgrind: 378,713 -> 343,687 instructions without metrics).
    The families and their samples are what prometheus_client's Counter and Histogram export,
    `_created` included.
    """

    def __init__(self, drives: Sequence[DriveLabels]) -> None:
        self._names = {(d.bus, d.address): d.drive for d in drives}
        self._series: dict[tuple[str, int, str, int], tuple[_Count, _Latency | None]] = {}
        """Per (bus, address, source, function): what a request of that kind counts in.
        Bounded: a closed set of sources, 256 function codes, the configured drives' addresses.
        Cleared by a reload; the counts themselves stay under their labels."""
        self._errors: dict[tuple[str, int, str, int], _Count] = {}
        """The same per (bus, address, source, exception code), for requests answered so."""
        self._requests: dict[tuple[str, ...], _Count] = {}
        """By label values (bus, drive, source, function): what is exported."""
        self._broadcasts: dict[tuple[str, ...], _Count] = {}
        self._exceptions: dict[tuple[str, ...], _Count] = {}
        self._latency: dict[tuple[str, ...], _Latency] = {}

    def observe(self, done: RequestDone) -> None:
        # Once per request on every bus: a dict lookup and a few additions.
        source = request_source(done.client)
        key = (done.bus, done.address, source, done.function)
        series = self._series.get(key)
        if series is None:
            series = self._series[key] = self._new_series(done, source)
        requests, latency = series
        requests.value += 1
        if latency is None:
            return
        if done.code is not None:  # a dead drive's every request: as cheap as the others
            error_key = (done.bus, done.address, source, done.code)
            errors = self._errors.get(error_key)
            if errors is None:
                drive = self.drive_name(done.bus, done.address)
                labels = (done.bus, drive, source, exception_label(done.code))
                errors = self._errors[error_key] = _series(self._exceptions, labels, _Count)
            errors.value += 1
        latency.observe(done.duration_s)

    def _new_series(self, done: RequestDone, source: str) -> tuple[_Count, _Latency | None]:
        """What one kind of request counts in: (requests, latency); latency None for a
        broadcast, which counts in its own family (it is no drive's request)."""
        function = function_label(done.function)
        if done.address == 0:
            return _series(self._broadcasts, (done.bus, source, function), _Count), None
        drive = self.drive_name(done.bus, done.address)
        return (
            _series(self._requests, (done.bus, drive, source, function), _Count),
            _series(self._latency, (done.bus, drive, source), _Latency),
        )

    def relabel(self, drives: Sequence[DriveLabels]) -> None:
        """A reload changed the drives: requests to them counted under their names from now."""
        self._names = {(d.bus, d.address): d.drive for d in drives}
        self._series.clear()
        self._errors.clear()

    def drive_name(self, bus: str, address: int) -> str:
        if address == 0:
            return BROADCAST
        return self._names.get((bus, address), f"address_{address}")

    def collect(self) -> Iterable[Metric]:
        yield _counter_family(
            f"{PREFIX}_requests",
            "Requests to a drive by who asked (tcp, poll, mqtt, probe) and function code",
            ["bus", "drive", "source", "function"],
            self._requests,
        )
        yield _counter_family(
            f"{PREFIX}_request_exceptions",
            "Requests answered with an exception code: the drive's own, or 0A/0B from the gateway",
            ["bus", "drive", "source", "code"],
            self._exceptions,
        )
        yield _counter_family(
            f"{PREFIX}_broadcast_requests",
            "Broadcasts (unit id 0) by who asked and function code: every drive, no reply",
            ["bus", "source", "function"],
            self._broadcasts,
        )
        name = f"{PREFIX}_request_duration_seconds"
        doc = "Time from a request reaching the bus to its answer: queue, retries, wire"
        labels = ["bus", "drive", "source"]
        latency = HistogramMetricFamily(name, doc, labels=labels)
        created = GaugeMetricFamily(f"{name}_created", doc, labels=labels)
        for values, histogram in self._latency.items():
            latency.add_metric(values, histogram.cumulative(), histogram.sum_s)
            created.add_metric(values, histogram.created)
        yield latency
        if created.samples and _created_series():  # as prometheus_client's Histogram does
            yield created


S = TypeVar("S", _Count, _Latency)


def _series(
    families: dict[tuple[str, ...], S], labels: tuple[str, ...], make: Callable[[], S]
) -> S:
    """The series of `labels`, begun now if new (several keys may share one: "other")."""
    series = families.get(labels)
    if series is None:
        series = families[labels] = make()
    return series


def _counter_family(
    name: str, doc: str, labels: list[str], counts: Mapping[tuple[str, ...], _Count]
) -> CounterMetricFamily:
    family = CounterMetricFamily(name, doc, labels=labels)
    with_created = _created_series()
    for values, count in counts.items():
        family.add_metric(values, count.value, created=count.created if with_created else None)
    return family


def _created_series() -> bool:
    """Whether prometheus_client exports `_created` samples (PROMETHEUS_DISABLE_CREATED_SERIES,
    or `disable_created_metrics()`): the same for these families as for its own."""
    return bool(getattr(prometheus_client_metrics, "_use_created", True))


class GatewayCollector(Collector):
    """Everything read at scrape time from the parts' own counters."""

    def __init__(self, service: Service, drives: Sequence[DriveLabels]) -> None:
        self.service = service
        self.drives = drives
        self._names = {(d.bus, d.address): d.drive for d in drives}

    def relabel(self, drives: Sequence[DriveLabels]) -> None:
        """A reload changed the drives: the next scrape shows the new ones by name."""
        self.drives = drives
        self._names = {(d.bus, d.address): d.drive for d in drives}

    def collect(self) -> Iterable[Metric]:
        yield from self._gateway()
        yield from self._buses()
        yield from self._drives()
        yield from self._tcp(self.service.tcp.stats)
        bridge = getattr(self.service, "mqtt", None)
        if bridge is not None:
            yield from _mqtt_families(bridge)
        if self.service.tcp.access is not None:
            yield self._access(self.service.tcp.access)
        console = getattr(self.service, "console", None)
        if console is not None:
            yield from _console_families(console)
        yield from self._store(self.service.events)

    def _gateway(self) -> Iterable[GaugeMetricFamily | InfoMetricFamily]:
        info = InfoMetricFamily(f"{PREFIX}_build", "Version and id of this gateway")
        labels = {
            "version": __version__,
            "gateway_id": self.service.settings.gateway_id,
            "event_loop": running_loop_name(),
            "python": platform.python_version(),
        }
        info.add_metric([], labels)
        yield info
        ready = GaugeMetricFamily(f"{PREFIX}_ready", "1 once started, 0 while starting/stopping")
        ready.add_metric([], 1.0 if self.service.phase is Phase.READY else 0.0)
        yield ready

    def _buses(self) -> Iterable[Metric]:
        buses = self.service.buses
        state = GaugeMetricFamily(
            f"{PREFIX}_bus_state", "1 for the bus's current state", labels=["bus", "state"]
        )
        depth = GaugeMetricFamily(
            f"{PREFIX}_bus_queue_depth", "Requests waiting for the line", labels=["bus"]
        )
        counters = {
            name: CounterMetricFamily(f"{PREFIX}_bus_{name}", doc, labels=["bus"])
            for name, doc in _BUS_COUNTERS.items()
        }
        busy = CounterMetricFamily(
            f"{PREFIX}_bus_busy_seconds",
            "Time the line was held by transactions, timeouts included (rate = utilisation)",
            labels=["bus"],
        )
        exchange = CounterMetricFamily(
            f"{PREFIX}_bus_exchange_seconds",
            "Time on the wire of answered exchanges: request, drive's delay, reply",
            labels=["bus"],
        )
        discarded = CounterMetricFamily(
            f"{PREFIX}_bus_discarded_bytes",
            "Bytes nobody asked for: late replies, echoes, noise",
            labels=["bus"],
        )
        excess = HistogramMetricFamily(
            f"{PREFIX}_bus_excess_gap_seconds",
            "Silence beyond the inter-frame gap (t3.5) between a reply and the next request, or "
            "since that request was queued if later, for a request the gap's end found waiting: "
            "the gateway's own share of each back-to-back transaction",
            labels=["bus"],
        )
        line = _LineFamilies()
        for name, bus in buses.items():
            excess.add_metric([name], bus.gap_excess.cumulative(), bus.gap_excess.sum_s)
            line.add(name, bus.line)
            for value in BusState:
                state.add_metric([name, str(value)], 1.0 if bus.state is value else 0.0)
            depth.add_metric([name], bus.queue_depth)
            stats = bus.stats
            for counter_name, family in counters.items():
                family.add_metric([name], getattr(stats, counter_name))
            busy.add_metric([name], sum(d.line_s for d in _snapshot(bus.drive_stats).values()))
            exchange.add_metric([name], stats.busy_s)
            discarded.add_metric([name], bus.line.discarded_bytes)
        yield state
        yield depth
        yield from counters.values()
        yield busy
        yield exchange
        yield discarded
        yield excess
        yield from line.families()

    def _drives(self) -> Iterable[CounterMetricFamily | GaugeMetricFamily | InfoMetricFamily]:
        buses = self.service.buses
        info = InfoMetricFamily(f"{PREFIX}_drive", "Configured drives", labels=["bus", "drive"])
        online = GaugeMetricFamily(
            f"{PREFIX}_drive_online",
            "1 while the drive answers, 0 once isolated as offline",
            labels=["bus", "drive"],
        )
        for d in self.drives:
            details = {"address": str(d.address), "unit_id": str(d.unit_id), "model": d.model}
            info.add_metric([d.bus, d.drive], details)
            offline = buses[d.bus].health.is_offline(d.address)
            online.add_metric([d.bus, d.drive], 0.0 if offline else 1.0)
        yield info
        yield online
        labels = ["bus", "drive"]
        counters = {
            name: CounterMetricFamily(f"{PREFIX}_drive_{name}", doc, labels=labels)
            for name, doc in _DRIVE_COUNTERS.items()
        }
        busy = CounterMetricFamily(
            f"{PREFIX}_drive_busy_seconds",
            "Time the line was held for this drive, timeouts included",
            labels=labels,
        )
        bad = CounterMetricFamily(
            f"{PREFIX}_drive_bad_replies",
            "Replies that could not be the answer: crc, truncated, address, function, echo",
            labels=[*labels, "kind"],
        )
        exceptions = CounterMetricFamily(
            f"{PREFIX}_drive_exceptions",
            "Exception replies from the drive itself, by code (INVT: 06 frame error, ...)",
            labels=[*labels, "code"],
        )
        for bus_name, bus in buses.items():
            for address, stats in sorted(_snapshot(bus.drive_stats).items()):
                if address == 0:
                    continue  # broadcasts are no drive's: bus_broadcasts_total counts them
                drive = self._name(bus_name, address)
                for counter_name, family in counters.items():
                    family.add_metric([bus_name, drive], getattr(stats, counter_name))
                busy.add_metric([bus_name, drive], stats.line_s)
                for kind, count in sorted(_snapshot(stats.bad_replies).items()):
                    bad.add_metric([bus_name, drive, kind], count)
                by_label: dict[str, int] = {}
                for code, count in _snapshot(stats.exceptions).items():
                    label = exception_label(code)
                    by_label[label] = by_label.get(label, 0) + count
                for label, count in sorted(by_label.items()):
                    exceptions.add_metric([bus_name, drive, label], count)
        yield from counters.values()
        yield busy
        yield bad
        yield exceptions

    def _tcp(self, stats: TcpStats) -> Iterable[CounterMetricFamily | GaugeMetricFamily]:
        clients = GaugeMetricFamily(f"{PREFIX}_tcp_clients", "Modbus-TCP clients connected")
        clients.add_metric([], len(stats.active))
        yield clients
        for name, doc in _TCP_COUNTERS.items():
            yield CounterMetricFamily(f"{PREFIX}_tcp_{name}", doc, value=getattr(stats, name))
        malformed = CounterMetricFamily(
            f"{PREFIX}_tcp_malformed_requests",
            "Requests answered at the front door without bus time (01H or 03H), by reason",
            labels=["reason"],
        )
        counts = dict(stats.malformed_requests)
        for reason in Reason:  # every reason, from the start: a fixed set of series
            malformed.add_metric([str(reason)], counts.get(reason, 0))
        yield malformed

    def _store(self, store: EventStore) -> Iterable[CounterMetricFamily | GaugeMetricFamily]:
        stats = store.stats
        for name, doc in _STORE_COUNTERS.items():
            yield CounterMetricFamily(f"{PREFIX}_store_{name}", doc, value=getattr(stats, name))
        yield GaugeMetricFamily(
            f"{PREFIX}_store_events_undelivered",
            "Events in the store the broker has not acknowledged yet",
            value=stats.undelivered,
        )
        yield GaugeMetricFamily(
            f"{PREFIX}_store_persistent",
            "1 when the store is on disk (storage.path), 0 when it could not be opened (memory)",
            value=1.0 if store.persistent else 0.0,
        )
        yield GaugeMetricFamily(
            f"{PREFIX}_store_events_in_memory",
            "Recorded events not in storage.path yet, waiting in memory for the disk to take "
            "them (a full or failing disk: /health says why); a restart loses them",
            value=store.status().events_in_memory,
        )

    def _access(self, access: AccessPolicy) -> CounterMetricFamily:
        denied = CounterMetricFamily(
            f"{PREFIX}_tcp_denied_by_rule",
            "Modbus-TCP requests refused by each modbus_tcp.access rule",
            labels=["rule"],
        )
        for rule, count in zip(access.rules, list(access.denied), strict=True):
            denied.add_metric([rule.label], count)
        return denied

    def _name(self, bus: str, address: int) -> str:
        if address == 0:
            return BROADCAST
        return self._names.get((bus, address), f"address_{address}")


def _snapshot(mapping: Mapping[K, V]) -> dict[K, V]:
    """A copy, so the samples of one scrape come from one moment."""
    return dict(mapping)


_BUS_COUNTERS = {
    "requests": "Requests handed to the bus",
    "transactions": "Attempts put on the wire, retries included",
    "retries": "Attempts repeated after a timeout or a bad reply",
    "timeouts": "Attempts without a reply within the response timeout",
    "failed": "Requests answered 0x0B after every attempt failed",
    "broadcasts": "Broadcasts (address 0) sent",
    "coalesced": "Identical queued reads answered by one transaction",
    "queue_full": "Requests refused with 0x0A because the queue was full",
    "offline_rejected": "Requests answered 0x0B at once because their drive is offline",
    "port_errors": "Times the serial port failed (unplugged, I/O error)",
    "reopens": "Times the serial port was opened again after failing",
    "late_replies": "Replies that came after their request timed out, set aside, never an answer",
    "resyncs": "Diagnostic echoes (08H) sent after a timeout to catch up with late replies",
}
_DRIVE_COUNTERS = {
    "transactions": "Attempts put on the wire for this drive, retries included",
    "retries": "Attempts repeated for this drive",
    "timeouts": "Attempts this drive did not answer in time",
    "failed": "Requests to this drive answered 0x0B after every attempt failed",
    "late_replies": "Replies from this drive that came after their request timed out, set aside",
    "resyncs": "Diagnostic echoes (08H) sent to this drive after a timeout, before anything else",
}
_TCP_COUNTERS = {
    "accepted": "Modbus-TCP connections accepted",
    "refused": "Modbus-TCP connections refused (limit or allowed_networks)",
    "requests": "Modbus-TCP requests received",
    "exceptions": "Modbus-TCP requests answered with an exception",
    "malformed": "Connections closed for a malformed MBAP frame",
    "idle_closed": "Connections closed after the idle timeout",
    "denied": "Requests refused by modbus_tcp.read_only or modbus_tcp.access",
    "evicted": "Connections closed to make room for a new one: they had never completed a request",
    "slow_closed": "Connections closed for a frame not completed in time, or no first request",
    "write_limited": "Writes answered 0AH: the client had max_queued_writes_per_client waiting",
    "tls_handshake_timeouts": (
        "TLS connections closed with their handshake not done within first_request_timeout_s"
    ),
    "tls_handshakes_failed": "TLS handshakes that failed (no or an untrusted client certificate)",
}


async def _scrape(registry: CollectorRegistry) -> Response:
    return Response(200, CONTENT_TYPE_LATEST, await exposition(registry))


class MetricsFeature:
    """Serves /metrics and /health while the gateway runs; a feature of the application."""

    def __init__(self, service: Service, settings: MetricsSettings) -> None:
        self.service = service
        self.settings = settings
        self.endpoint: HttpEndpoint | None = None
        self._requests: RequestMetrics | None = None
        self._collector: GatewayCollector | None = None
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
        registry.register(self._requests)
        self._collector = GatewayCollector(self.service, drives)
        registry.register(self._collector)
        ProcessCollector(registry=registry)
        self._registry = registry
        for bus in self.service.buses.values():
            bus.add_request_observer(self._requests.observe)
        self.endpoint = self._endpoint(self.settings)
        await self.endpoint.start()
        log.info("metrics and health on http://%s:%d/", self.settings.host, self.endpoint.port)

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
        if self._requests is not None and self._collector is not None:
            self._requests.relabel(drives)
            self._collector.relabel(drives)

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
        )
        return {"gateway_id": service.settings.gateway_id, "version": __version__, **report}

    def _health(self) -> Response:
        report = self._report()
        status = HTTPStatus.OK if report["ready"] else HTTPStatus.SERVICE_UNAVAILABLE
        return Response(status, "application/json", json.dumps(report).encode() + b"\n")

    def _live(self) -> Response:
        return Response(HTTPStatus.OK, "application/json", json.dumps(self._report()).encode())


_LINE_METRICS: tuple[
    tuple[str, type[CounterMetricFamily | GaugeMetricFamily], str, Callable[[SerialLine], float]],
    ...,
] = (
    (
        "line_garbage_bytes",
        CounterMetricFamily,
        "Bytes skipped before replies that could not start them (transceiver glitches, noise)",
        lambda line: line.garbage_bytes,
    ),
    (
        "line_echoes",
        CounterMetricFamily,
        "Requests the adapter handed back though the bus has echo: false (set echo: true)",
        lambda line: line.echoes,
    ),
    (
        "line_reply_silence_max_seconds",
        GaugeMetricFamily,
        "Longest silence seen inside a reply (an adapter delivering in bursts shows here)",
        lambda line: line.longest_reply_silence_s,
    ),
    (
        "line_gap_lead_seconds",
        GaugeMetricFamily,
        "How long before the inter-frame gap ends the line wakes to choose the next request "
        "(learnt from its wake-ups: about their 95th percentile of lateness while the event "
        "loop's lines spin within their budget, their lower quartile past it)",
        lambda line: line.gap_lead.lead_s,
    ),
    (
        "line_gap_spin_seconds",
        CounterMetricFamily,
        "CPU time spent waiting out the gap's last microseconds after an early wake-up",
        lambda line: line.gap_lead.spun_s,
    ),
)
"""Per line: what its hardware does to replies (glitches, echoes, bursts) and what keeping its
gap costs (`gateway.bus.line`): name, kind, help, and how to read it off the line."""


class _LineFamilies:
    """The `_LINE_METRICS` families, one sample per bus."""

    def __init__(self) -> None:
        self._families = [
            (kind(f"{PREFIX}_{name}", doc, labels=["bus"]), read)
            for name, kind, doc, read in _LINE_METRICS
        ]

    def add(self, bus: str, line: SerialLine) -> None:
        for family, read in self._families:
            family.add_metric([bus], read(line))

    def families(self) -> Iterable[CounterMetricFamily | GaugeMetricFamily]:
        return [family for family, _ in self._families]


def _mqtt_families(bridge: MqttBridge) -> Iterable[CounterMetricFamily | GaugeMetricFamily]:
    connected = GaugeMetricFamily(
        f"{PREFIX}_mqtt_connected", "1 while the bridge is connected to the broker"
    )
    connected.add_metric([], 1.0 if bridge.connected.is_set() else 0.0)
    yield connected
    yield CounterMetricFamily(
        f"{PREFIX}_mqtt_messages_published",
        "Messages the bridge published (states, availability, events, answers, discovery)",
        value=bridge.stats.published,
    )
    yield CounterMetricFamily(
        f"{PREFIX}_mqtt_messages_dropped",
        "Events dropped before the broker had them (the store's bounds: the broker was away "
        "too long); states are never dropped, only superseded by newer ones",
        value=bridge.publisher.events.stats.events_dropped,
    )
    commands = CounterMetricFamily(
        f"{PREFIX}_mqtt_commands",
        "Commands answered, by status: ok, or why not (retained, stale, busy, ...)",
        labels=["status"],
    )
    statuses = dict(bridge.commands.statuses)
    statuses["busy"] = statuses.get("busy", 0) + bridge.stats.busy  # refused before their turn
    for status, count in sorted(statuses.items()):
        commands.add_metric([status], count)
    yield commands


def _console_families(console: ConsoleFeature) -> Iterable[CounterMetricFamily]:
    timeouts = CounterMetricFamily(
        f"{PREFIX}_console_request_timeouts",
        "Console connections closed: a request's head or body not there within "
        "console.request_timeout_s",
        labels=["phase"],
    )
    closed = console.deadlines.closed
    timeouts.add_metric(["head"], closed.head)
    timeouts.add_metric(["body"], closed.body)
    yield timeouts
    if console.console is None:
        return
    logins = CounterMetricFamily(
        f"{PREFIX}_console_logins",
        "Console login attempts by result: ok, failed (wrong name or password), throttled "
        "(refused before the password was checked: that name and address must wait)",
        labels=["result"],
    )
    counts = console.console.logins
    for result in ("ok", "failed", "throttled"):
        logins.add_metric([result], getattr(counts, result))
    yield logins


_STORE_COUNTERS = {
    "events_recorded": "Events recorded (faults, availability, ports, commands, writes, reloads)",
    "events_delivered": "Events the broker acknowledged",
    "events_dropped": "Events removed before the broker had them (storage.max_mb or max_age_days)",
    "write_failures": "Writes to the store that failed (a full or failing disk); retried",
    "events_not_stored": "Events pushed out of memory while the disk could not take them, though "
    "the broker had them (gone from the history only)",
}
