"""The store's outage buffer: running values kept while a connection is away, read back in the
order polled per connection, gone once delivered; past its size bound the oldest go, counted,
logged once and handed to their connection as a gap to mark."""

from __future__ import annotations

import logging
import time
from pathlib import Path

import pytest

from gateway.config import StorageConfig
from gateway.store.outage_rows import ROW_OVERHEAD
from tests.support.store import running_store


async def test_samples_come_back_in_order_per_connection_and_go_once_delivered(
    tmp_path: Path,
) -> None:
    config = StorageConfig(path=str(tmp_path / "events.db"))
    t0 = time.time() - 60  # within outage_buffer_hours
    async with running_store(config) as store:
        for n in range(5):
            store.keep_sample("json", "pump1", {"output_current_a": n / 10}, t0 + n)
            store.keep_sample("sparkplug", "pump1", {"output_current_a": n / 10}, t0 + n)
        await store.flush()
        kept = await store.outage_samples("json", 0, 100)
        assert [(s.time, s.values) for s in kept] == [
            (t0 + n, {"output_current_a": n / 10}) for n in range(5)
        ]
        store.outage_delivered("json", kept[2].id)
        store.keep_sample("json", "pump1", {"output_current_a": 9.9}, t0 + 10)
        await store.flush()
        left = await store.outage_samples("json", 0, 100)
        assert [s.time for s in left] == [t0 + 3, t0 + 4, t0 + 10]
        assert left[-1].id > kept[-1].id, "an id is never given twice"
        assert len(await store.outage_samples("sparkplug", 0, 100)) == 5  # its own
        assert store.stats.outage_samples_dropped == 0


async def test_past_its_bound_the_oldest_go_counted_logged_once_and_the_gap_kept(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.WARNING, logger="gateway.store")
    bound_mb = 0.01  # 10 kB: some 130 samples of one value
    config = StorageConfig(path=str(tmp_path / "events.db"), outage_buffer_mb=bound_mb)
    start = time.time() - 1000
    async with running_store(config) as store:
        for batch in range(3):
            for n in range(200):
                at = start + batch * 200 + n
                store.keep_sample("json", "pump1", {"output_current_a": float(n)}, at)
            await store.flush()
        kept = await store.outage_samples("json", 0, 1000)
        gaps = store.outage_gaps("json")
        assert store.outage_gaps("json") == [], "each gap handed over once"
    size = sum(len('{"output_current_a":0.0}') + ROW_OVERHEAD for _ in kept)
    assert size <= bound_mb * 1024 * 1024 * 1.05
    assert kept[-1].time == start + 599, "the newest are kept"
    dropped = sum(gap.samples for gap in gaps)
    assert dropped == store.stats.outage_samples_dropped == 600 - len(kept)
    assert min(g.start for g in gaps) == start
    assert max(g.end for g in gaps) < kept[0].time
    said = [r for r in caplog.records if "went before they were delivered" in r.getMessage()]
    assert len(said) == 1, [r.getMessage() for r in said]


def test_the_outage_buffer_is_part_of_max_mb() -> None:
    assert StorageConfig(max_mb=64).outage_buffer == 16
    with pytest.raises(ValueError, match="part of max_mb"):
        StorageConfig(max_mb=8, outage_buffer_mb=10)


async def test_older_than_its_hours_they_go_with_their_gap(tmp_path: Path) -> None:
    config = StorageConfig(path=str(tmp_path / "events.db"), outage_buffer_hours=1)
    async with running_store(config) as store:
        old, now = time.time() - 2 * 3600, time.time()
        store.keep_sample("json", "fan2", {"state": "running_forward"}, old)
        store.keep_sample("json", "fan2", {"state": "stopped"}, now)
        await store.flush()
        assert [s.values for s in await store.outage_samples("json", 0, 10)] == [
            {"state": "stopped"}
        ]
        (gap,) = store.outage_gaps("json")
        assert (gap.drive, gap.start, gap.samples) == ("fan2", old, 1)
