"""The history of polled values in the store, on a real SQLite file: averaged per step, kept
across a restart, bounded by storage.max_mb (the history goes before any event) and by
storage.history_days."""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import AsyncIterator
from pathlib import Path

from gateway.config import StorageConfig
from gateway.settings.local import StoreSettings
from gateway.store import EventStore
from gateway.store.history import HistoryRecorder, Value, series
from gateway.store.records import HistoryPoint
from gateway.tasks import ServiceTasks

VALUES = {f"value_{n:02d}": 1000.0 + n for n in range(14)}
"""About what a GD350's running values take: 14 numbers and the state."""


@contextlib.asynccontextmanager
async def running_store(config: StorageConfig) -> AsyncIterator[EventStore]:
    tasks = ServiceTasks()
    async with asyncio.TaskGroup() as group:
        tasks.bind(group)
        settings = StoreSettings(
            config.resolved_path("test"),
            config.max_mb,
            config.max_age_days,
            True,
            100_000,
            config.history_days,
            config.history_step_s,
        )
        store = EventStore(settings, tasks)
        await store.start()
        try:
            yield store
        finally:
            await store.stop()


def test_a_step_averages_numbers_keeps_the_last_text_and_closes_with_the_next() -> None:
    kept: list[HistoryPoint] = []
    now = [1000.0]
    recorder = HistoryRecorder(kept.append, 60.0, clock=lambda: now[0])
    for at, hz, state, running in (
        (1020.0, 10.0, "stopped", False),
        (1050.0, 20.0, "running", True),
    ):
        now[0] = at
        recorder.state_updated("pump1", {"output_frequency_hz": hz, "state": state, "run": running})
    assert kept == []  # the step isn't over
    now[0] = 1085.0
    recorder.state_updated("pump1", {"output_frequency_hz": 40.0, "last_seen": "x"})
    (point,) = kept
    assert point == HistoryPoint(
        "pump1", 1020.0, {"output_frequency_hz": 15.0, "run": 0.5, "state": "running"}
    )
    recorder.finish()  # the gateway stops: the step begun is kept as far as it went
    assert kept[-1] == HistoryPoint("pump1", 1080.0, {"output_frequency_hz": 40.0})


def test_more_points_than_asked_for_are_merged() -> None:
    points: list[tuple[float, dict[str, Value]]] = [
        (60.0 * n, {"hz": float(n), "state": f"s{n}"}) for n in range(10)
    ]
    shown = series(points, ["hz", "state", "missing"], 60.0, 5)
    assert shown.times == [0.0, 120.0, 240.0, 360.0, 480.0]
    assert shown.columns[0] == [0.5, 2.5, 4.5, 6.5, 8.5]
    assert shown.columns[1] == ["s1", "s3", "s5", "s7", "s9"]
    assert shown.columns[2] == [None] * 5
    assert shown.step_s == 120.0


async def test_the_history_goes_before_any_event_past_max_mb(tmp_path: Path) -> None:
    path = tmp_path / "events.db"
    config = StorageConfig(path=str(path), max_mb=0.25)
    bound = int(0.25 * 1024 * 1024)
    start = time.time() - 3000 * 60
    async with running_store(config) as store:
        for n in range(20):
            store.record("command", {"n": n})
        for n in range(3000):  # about 1.2 MB of history: five times the bound
            store.history.keep(HistoryPoint("pump1", start + 60 * n, {**VALUES, "state": "run"}))
            if n % 200 == 199:
                await store.flush()
        await store.flush()
        assert await store.size_bytes() <= bound
        events = await store.undelivered(100)
        rows = await store.history_rows()
        kept = await store.history_points("pump1", 0.0, time.time())
    assert path.stat().st_size <= bound
    assert [e.data["n"] for e in events] == list(range(20))  # not one event went
    assert 0 < rows < 3000
    # Oldest first out: what is left is the newest, without a gap.
    assert [at for at, _ in kept] == [start + 60 * n for n in range(3000 - rows, 3000)]


async def test_history_older_than_history_days_goes_and_the_rest_survives_a_restart(
    tmp_path: Path,
) -> None:
    config = StorageConfig(path=str(tmp_path / "events.db"), history_days=1)
    now = time.time()
    async with running_store(config) as store:
        store.history.keep(HistoryPoint("pump1", now - 2 * 86400, {"hz": 1.0}))
        store.history.keep(HistoryPoint("pump1", now - 60, {"hz": 2.0}))
        await store.flush()
    async with running_store(config) as store:
        kept = await store.history_points("pump1", 0.0, now + 1)
    assert kept == [(now - 60, {"hz": 2.0})]


async def test_a_step_a_restart_cut_in_two_keeps_what_each_run_polled(tmp_path: Path) -> None:
    config = StorageConfig(path=str(tmp_path / "events.db"))
    step = time.time() - 30
    async with running_store(config) as store:
        store.history.keep(HistoryPoint("pump1", step, {"hz": 30.0, "state": "running_forward"}))
        await store.flush()
    async with running_store(config) as store:
        # The new run's first poll of the step had read only the state block.
        store.history.keep(HistoryPoint("pump1", step, {"state": "stopped"}))
        waiting = await store.history_points("pump1", 0.0, step + 1)
        await store.flush()
        written = await store.history_points("pump1", 0.0, step + 1)
        rows = await store.history_rows()
    assert waiting == written == [(step, {"hz": 30.0, "state": "stopped"})]
    assert rows == 1


async def test_history_days_0_keeps_no_history(tmp_path: Path) -> None:
    config = StorageConfig(path=str(tmp_path / "events.db"), history_days=0)
    async with running_store(config) as store:
        for _ in range(3):
            store.history.state_updated("pump1", {"hz": 1.0})
        store.history.finish()
        await store.flush()
        assert await store.history_rows() == 0


def test_never_more_points_than_asked_for_whatever_the_gaps() -> None:
    # A drive polled, offline, polled again: points a step apart, then a gap, unaligned.
    points: list[tuple[float, dict[str, Value]]] = [
        (start + 60.0 * n, {"hz": 1.0}) for start in (30.0, 4000.0, 9070.0) for n in range(7)
    ]
    for asked in (1, 2, 3, 5, 8, 20, 100):
        shown = series(points, ["hz"], 60.0, asked)
        assert 1 <= len(shown.times) <= asked
        assert shown.times == sorted(shown.times)


async def test_a_window_is_reduced_in_the_database_as_series_merges_it(tmp_path: Path) -> None:
    config = StorageConfig(path=str(tmp_path / "events.db"), history_days=90)
    start = 1_764_000_000.0 - 1_764_000_000.0 % 3600
    points: list[tuple[float, dict[str, Value]]] = [
        (start + 60 * n, {"hz": float(n % 7), "state": f"s{n}"} if n % 5 else {"hz": -1.5})
        for n in range(1000)
    ]
    async with running_store(config) as store:
        for at, found in points:
            store.history.keep(HistoryPoint("pump1", at, found))
        await store.flush()
        span_s, reduced = await store.history_window("pump1", start, start + 60_000, 101)
        raw = await store.history_points("pump1", start, start + 60_000)
        as_is = await store.history_window("pump1", start, start + 60_000, 1000)
    assert as_is == (60.0, points)  # no more than asked for: as they are
    assert span_s == 600.0
    assert raw == points
    shown = series(points, ["hz", "state"], 60.0, 100)  # ten steps a point: 600 s
    assert shown.step_s == 600.0
    assert [at for at, _ in reduced] == shown.times
    assert [found["hz"] for _, found in reduced] == shown.columns[0]
    assert [found.get("state") for _, found in reduced] == shown.columns[1]
