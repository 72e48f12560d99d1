"""Redundancy's metric families, read at scrape time: the role this gateway is in, its changes,
another master's frames heard, and the keys the other box's configuration differs in. Published
without `redundancy:` too (a gateway alone is its lines' active master, and has no changes): a
dashboard's query needs no second form."""

from __future__ import annotations

from collections.abc import Callable, Iterable

from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily
from prometheus_client.registry import Collector

from gateway.metric_families import PREFIX
from gateway.redundancy.roles import Redundancy, Role


class RedundancyMetrics(Collector):
    def __init__(self, current: Callable[[], Redundancy | None]) -> None:
        self._current = current

    def collect(self) -> Iterable[CounterMetricFamily | GaugeMetricFamily]:
        redundancy = self._current()
        role = Role.ACTIVE if redundancy is None else redundancy.role
        gauge = GaugeMetricFamily(
            f"{PREFIX}_redundancy_role",
            "1 for the role this gateway is in: active (the line's master), listening (asked "
            "to be active, off the line until it is silent) or standby (never transmits)",
            labels=["role"],
        )
        changes = CounterMetricFamily(
            f"{PREFIX}_redundancy_role_changes",
            "Changes into each role since start (takeovers: into active)",
            labels=["role"],
        )
        for each in Role:
            gauge.add_metric([each.value], 1.0 if each is role else 0.0)
            count = 0 if redundancy is None else redundancy.changes[each]
            changes.add_metric([each.value], float(count))
        yield gauge
        yield changes
        peer = None if redundancy is None else redundancy.peer_config
        yield GaugeMetricFamily(
            f"{PREFIX}_redundancy_peer_config_differences",
            "Keys both boxes must share whose values differ between this box's configuration "
            "and the other box's, as it announced it on MQTT (0: alike, or not heard)",
            value=0.0 if peer is None else float(len(peer.differs)),
        )
        yield GaugeMetricFamily(
            f"{PREFIX}_redundancy_fit",
            "1 while this box can be the line's master and hold the virtual address, 0 while "
            "it can't (no port open on any line: its adapter; or, asked active, it has heard "
            "another master for seconds: a cut between the boxes)",
            value=1.0 if redundancy is None or redundancy.fit else 0.0,
        )
        yield CounterMetricFamily(
            f"{PREFIX}_redundancy_foreign_frames",
            "Another master's requests heard on a line while this gateway was active: each "
            "makes it leave the line at once",
            value=0.0 if redundancy is None else float(redundancy.foreign_frames),
        )
