"""/metrics made a family (or a piece of a large one) at a time: the same text Prometheus always
got, and a line's work (a gap's end) runs in between instead of waiting for the whole scrape."""

from __future__ import annotations

import asyncio
from collections.abc import Iterable

from prometheus_client import (
    CollectorRegistry,
    Counter,
    Gauge,
    Histogram,
    Info,
    generate_latest,
)
from prometheus_client.core import GaugeHistogramMetricFamily, GaugeMetricFamily
from prometheus_client.metrics_core import Metric
from prometheus_client.registry import Collector

from gateway.bus import RequestDone
from gateway.bus.metrics import DriveLabels
from gateway.bus.request_metrics import RequestMetrics
from gateway.exposition import SAMPLES_PER_PIECE, exposition


async def test_the_text_is_the_one_generate_latest_makes() -> None:
    registry = CollectorRegistry(auto_describe=True)
    requests = RequestMetrics([DriveLabels("pump1", "line1", 1, 1, "gd350")])
    registry.register(requests)
    requests.observe(*RequestDone("line1", 1, 3, "tcp:10.0.0.5:50123", 0.004, None))
    requests.observe(*RequestDone("line1", 1, 6, "mqtt", 0.03, 0x02))
    Counter("frames", "frames sent", ["bus"], registry=registry).labels("line1").inc(7)
    Gauge("lead_seconds", "gap lead", registry=registry).set(0.000075)
    Histogram("gap_seconds", "gap", registry=registry).observe(0.0021)
    made = await exposition(registry)
    assert made == generate_latest(registry)
    assert b'frames_total{bus="line1"} 7.0' in made
    assert b"invt_gateway_requests_total" in made


class _Families(Collector):
    """Three families; says when each is collected."""

    def __init__(self, events: list[str]) -> None:
        self.events = events

    def collect(self) -> Iterable[Metric]:
        for name in ("state_word", "fault_code", "frequency"):
            self.events.append(name)
            yield GaugeMetricFamily(name, "a drive's value", value=1)


async def test_the_loop_runs_other_work_between_families() -> None:
    events: list[str] = []
    registry = CollectorRegistry()
    registry.register(_Families(events))
    events.clear()
    asyncio.get_running_loop().call_soon(events.append, "gap ended")
    await exposition(registry)
    # In one piece, the gap's end would have waited for all three families.
    assert events == ["state_word", "gap ended", "fault_code", "frequency"]


def _large_registry() -> CollectorRegistry:
    """Families several pieces long, of every kind whose text has more than one block, with
    label values that need escaping (a newline, a quote, a backslash)."""
    registry = CollectorRegistry(auto_describe=True)
    requests = Counter("requests", "requests by client", ["client"], registry=registry)
    duration = Histogram("duration_seconds", "by client", ["client"], registry=registry)
    names = Info("drive", "nameplate", ["bus"], registry=registry)
    for n in range(3 * SAMPLES_PER_PIECE):
        client = f'tcp:10.0.{n // 250}.{n % 250}:502 "scada"\nline\\{n}'
        requests.labels(client).inc(n)
        duration.labels(client).observe(n / 1000)
        names.labels(f"line{n}").info({"model": "gd350", "rated_kw": str(n)})
    registry.register(_GaugeHistograms(2 * SAMPLES_PER_PIECE + 7))
    return registry


class _GaugeHistograms(Collector):
    """A gauge histogram: its _gsum and _gcount samples go to blocks of their own."""

    def __init__(self, series: int) -> None:
        self.series = series

    def collect(self) -> Iterable[Metric]:
        family = GaugeHistogramMetricFamily("queue_depth", "requests waiting", labels=["bus"])
        for n in range(self.series):
            family.add_metric([f"line{n}"], [("1.0", n), ("+Inf", 2 * n)], gsum_value=n / 2)
        yield family


async def test_large_families_made_in_pieces_are_the_text_generate_latest_makes() -> None:
    registry = _large_registry()
    made = await exposition(registry)
    assert made == generate_latest(registry)
    assert made.count(b"# TYPE requests_created gauge") == 1  # one block, however many pieces


async def test_the_loop_runs_other_work_inside_a_large_family() -> None:
    """A 1,000-sample family is ten pieces: the loop gets at least nine turns inside it."""
    registry = CollectorRegistry()
    registry.register(_GaugeHistograms(SAMPLES_PER_PIECE * 10 // 3))  # 3 samples a series
    turns = 0
    stop = False

    async def count_turns() -> None:
        nonlocal turns
        while not stop:
            turns += 1
            await asyncio.sleep(0)

    counting = asyncio.create_task(count_turns())
    await asyncio.sleep(0)
    turns = 0
    await exposition(registry)
    stop = True
    await counting
    assert turns >= 9
