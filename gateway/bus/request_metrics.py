"""The requests the buses answer, as their request observer reports each: how many, from whom,
which function, which exception code, how fast (`invt_gateway_requests_total`, the exceptions,
the broadcasts, the latency histogram). What has to be seen per request, by who asked and how
long it took, can't be read off the buses' counters at scrape time (`bus.metrics`)."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from functools import lru_cache
from typing import TypeVar

from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, HistogramMetricFamily
from prometheus_client.metrics_core import Metric
from prometheus_client.registry import Collector

from gateway.buckets import Buckets
from gateway.bus.bus import RequestDone
from gateway.bus.metrics import DriveLabels, DriveNames, exception_label
from gateway.metric_families import OTHER, PREFIX, created_series
from gateway.modbus.functions import FUNCTIONS

SOURCES = ("tcp", "poll", "mqtt", "opcua", "probe")
"""Who asked: clients are named "tcp:<peer>", "poll", "mqtt", "opcua" (the OPC UA server's commands
and parameter reads) and "probe" (the bus's own)."""
MAX_SERIES_KEYS = 4096
"""`RequestMetrics._series` holds at most this many keys (one per client, drive and function
asked): a gateway whose clients reconnect all day must not grow it without end."""
LATENCY_BUCKETS = (0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0)
"""Seconds: one short read at 115200 baud takes ~3 ms, a 16-word read at 9600 ~50 ms, and a
queue behind a dead drive seconds."""


@lru_cache(maxsize=4096)
def request_source(client: str) -> str:
    """ "tcp:10.0.0.5:51234" → "tcp"; anything unforeseen → "other" (bounded label values)."""
    head = client.split(":", 1)[0]
    return head if head in SOURCES else OTHER


def function_label(function: int) -> str:
    """The codes of the function-code registry by name, any other `other`: a client choosing
    random codes must not grow the metrics by a series per code."""
    return f"{function:02X}" if function in FUNCTIONS else OTHER


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
        self.drive_name = DriveNames(drives)
        self._series: dict[tuple[str, int, str, int], tuple[_Count, _Latency | None]] = {}
        """Per (bus, address, client, function): what a request of that kind counts in, found
        with one lookup per request (the client's source, `request_source`, worked out only
        for a new key). Bounded: emptied once it holds `MAX_SERIES_KEYS` (clients come and go
        with their connections), and by a reload; the counts themselves stay under their
        labels."""
        self._errors: dict[tuple[str, int, str, int], _Count] = {}
        """The same per (bus, address, source, exception code), for requests answered so."""
        self._requests: dict[tuple[str, ...], _Count] = {}
        """By label values (bus, drive, source, function): what is exported."""
        self._broadcasts: dict[tuple[str, ...], _Count] = {}
        self._exceptions: dict[tuple[str, ...], _Count] = {}
        self._latency: dict[tuple[str, ...], _Latency] = {}

    def observe(
        self,
        bus: str,
        address: int,
        function: int,
        client: str,
        duration_s: float,
        code: int | None,
    ) -> None:
        """The bus's request observer (`gateway.bus.bus.RequestObserver`): a `RequestDone`'s
        fields."""
        # Once per request on every bus: a dict lookup and a few additions.
        key = (bus, address, client, function)
        series = self._series.get(key)
        if series is None:
            if len(self._series) >= MAX_SERIES_KEYS:
                self._series.clear()
            done = RequestDone(bus, address, function, client, duration_s, code)
            series = self._series[key] = self._new_series(done, request_source(client))
        requests, latency = series
        requests.value += 1
        if latency is None:
            return
        if code is not None:  # a dead drive's every request: as cheap as the others
            source = request_source(client)
            error_key = (bus, address, source, code)
            errors = self._errors.get(error_key)
            if errors is None:
                drive = self.drive_name(bus, address)
                labels = (bus, drive, source, exception_label(code))
                errors = self._errors[error_key] = _series(self._exceptions, labels, _Count)
            errors.value += 1
        latency.observe(duration_s)

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
        self.drive_name = DriveNames(drives)
        self._series.clear()
        self._errors.clear()

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
        if created.samples and created_series():  # as prometheus_client's Histogram does
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
    with_created = created_series()
    for values, count in counts.items():
        family.add_metric(values, count.value, created=count.created if with_created else None)
    return family
