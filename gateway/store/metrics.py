"""The event store's metric families, read at scrape time: events recorded, delivered, dropped,
waiting for the broker or for the disk, and whether the store is on disk at all."""

from __future__ import annotations

from collections.abc import Iterable

from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily
from prometheus_client.registry import Collector

from gateway.metric_families import PREFIX
from gateway.store.events import EventStore


class StoreMetrics(Collector):
    def __init__(self, store: EventStore) -> None:
        self.store = store

    def collect(self) -> Iterable[CounterMetricFamily | GaugeMetricFamily]:
        store = self.store
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


_STORE_COUNTERS = {
    "events_recorded": "Events recorded (faults, availability, ports, commands, writes, reloads)",
    "events_delivered": "Events the broker acknowledged",
    "events_dropped": "Events removed before the broker had them (storage.max_mb or max_age_days)",
    "write_failures": "Writes to the store that failed (a full or failing disk); retried",
    "events_not_stored": "Events pushed out of memory while the disk could not take them, though "
    "the broker had them (gone from the history only)",
}
