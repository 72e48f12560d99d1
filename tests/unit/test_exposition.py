"""/metrics made a family at a time: the same text Prometheus always got, and a line's work
(a gap's end) runs between the families instead of waiting for the whole scrape."""

from __future__ import annotations

import asyncio
from collections.abc import Iterable

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram, generate_latest
from prometheus_client.core import GaugeMetricFamily
from prometheus_client.metrics_core import Metric
from prometheus_client.registry import Collector

from gateway.bus import RequestDone
from gateway.bus.metrics import DriveLabels
from gateway.bus.request_metrics import RequestMetrics
from gateway.exposition import exposition


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
