"""The event store on a real SQLite file: ids across restarts, the size bound, fault history,
and a store that can't be opened."""

from __future__ import annotations

import contextlib
import logging
import sqlite3
import time
from pathlib import Path

import pytest

from gateway.config import StorageConfig
from gateway.poller.drive_state import DriveEvent, EventKind, iso_time
from gateway.profile.telemetry import Telemetry
from tests.support.store import running_store


def fault(drive: str, code: int, at: float, raised: bool = True) -> DriveEvent:
    kind = EventKind.FAULT_RAISED if raised else EventKind.FAULT_CLEARED
    data: Telemetry = {
        "fault_code": code,
        "fault_name": f"F{code}",
        "fault_description": f"F{code}: test",
    }
    snapshot: Telemetry = {"output_frequency_hz": 12.5, "bus_voltage_v": 540.0, "fault_code": code}
    return DriveEvent(kind, drive, data, at, snapshot if raised else {})


async def test_ids_keep_increasing_across_restarts_and_trims(tmp_path: Path) -> None:
    config = StorageConfig(path=str(tmp_path / "events.db"))
    async with running_store(config) as store:
        for n in range(3):
            store.record("command", {"n": n})
        await store.flush()
        first = await store.undelivered(10)
        store.delivered([e.id for e in first])
    async with running_store(config) as store:
        assert await store.undelivered(10) == []  # the broker had them: not sent again
        store.record("command", {"n": 3})
        await store.flush()
        (after,) = await store.undelivered(10)
    assert [e.id for e in first] == [1, 2, 3]
    assert after.id == 4
    # Even with every row gone (an operator emptied the table), an id is never given twice.
    with contextlib.closing(sqlite3.connect(config.path or "")) as db:
        db.execute("DELETE FROM events")
        db.commit()
    async with running_store(config) as store:
        store.record("command", {"n": 4})
        await store.flush()
        (latest,) = await store.recent_events(1)
    assert latest.id == 5


async def test_undelivered_events_wait_for_the_next_run_in_order(tmp_path: Path) -> None:
    config = StorageConfig(path=str(tmp_path / "events.db"))
    start = round(time.time()) - 60.0
    async with running_store(config) as store:
        for n in range(5):
            store.record("command", {"n": n}, at=start + n)
        await store.flush()
        sent = await store.undelivered(2)
        store.delivered([sent[0].id])  # the second was published, never acknowledged
    async with running_store(config) as store:
        waiting = await store.undelivered(100)
        assert store.stats.undelivered == 4
    assert [e.data["n"] for e in waiting] == [1, 2, 3, 4]
    assert [e.time - start for e in waiting] == [1.0, 2.0, 3.0, 4.0]  # their own times
    assert waiting[0].payload()["time"] == iso_time(start + 1)


async def test_the_size_bound_holds_oldest_out_counted_and_logged(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    path = tmp_path / "events.db"
    config = StorageConfig(path=str(path), max_mb=0.1)
    bound = int(0.1 * 1024 * 1024)
    caplog.set_level(logging.WARNING, "gateway.store")
    async with running_store(config) as store:
        for n in range(3000):  # about 300 kB of events: three times the bound
            store.record("command", {"drive": "pump1", "n": n, "note": "x" * 40})
            if n % 100 == 99:
                await store.flush()  # as they would come: a few at a time
        await store.flush()
        assert await store.size_bytes() <= bound
        waiting = await store.undelivered(5000)
        dropped = store.stats.events_dropped
    assert path.stat().st_size <= bound  # the file itself, once closed
    assert not path.with_name("events.db-wal").exists()
    assert 0 < len(waiting) < 3000
    assert dropped == 3000 - len(waiting)
    # Oldest first out: what is left is the newest, without a gap.
    assert [e.data["n"] for e in waiting] == list(range(3000 - len(waiting), 3000))
    assert [e.id for e in waiting] == list(range(3001 - len(waiting), 3001))
    warnings = [r.getMessage() for r in caplog.records if "dropped" in r.getMessage()]
    assert warnings, "a drop must be logged"
    assert "storage.max_mb (0.1) reached" in warnings[0]
    assert len(warnings) == 1  # not one line per write: the next after a minute


async def test_events_older_than_max_age_go_at_start(tmp_path: Path) -> None:
    config = StorageConfig(path=str(tmp_path / "events.db"), max_age_days=1)
    async with running_store(config) as store:
        store.record("command", {"n": "old"}, at=time.time() - 2 * 86400)
        store.record("command", {"n": "new"})
        await store.flush()
    async with running_store(config) as store:
        waiting = await store.undelivered(10)
        assert store.stats.events_dropped == 1
    assert [e.data["n"] for e in waiting] == ["new"]


async def test_fault_history_with_snapshots_newest_first(tmp_path: Path) -> None:
    config = StorageConfig(path=str(tmp_path / "events.db"))
    t = round(time.time()) - 3600.0
    async with running_store(config) as store:
        store.drive_event(fault("pump1", 11, t))
        store.drive_event(fault("pump1", 11, t + 2.5, raised=False))
        store.drive_event(fault("fan2", 5, t + 3))
        store.drive_event(fault("pump1", 23, t + 10))
        await store.flush()
    async with running_store(config) as store:
        # After a restart the poller sees the fault still raised: the same fault, not a new one.
        store.drive_event(fault("pump1", 23, t + 100))
        await store.flush()
        history = [f.as_json() for f in await store.fault_history("pump1", 10)]
        one = [f.as_json() for f in await store.fault_history("pump1", 1)]
        events = await store.recent_events(10, drive="pump1")
    assert history == [
        {
            "code": 23,
            "name": "F23",
            "description": "F23: test",
            "raised": iso_time(t + 10),
            "cleared": None,
            "duration_s": None,
            "snapshot": {"output_frequency_hz": 12.5, "bus_voltage_v": 540.0},
        },
        {
            "code": 11,
            "name": "F11",
            "description": "F11: test",
            "raised": iso_time(t),
            "cleared": iso_time(t + 2.5),
            "duration_s": 2.5,
            "snapshot": {"output_frequency_hz": 12.5, "bus_voltage_v": 540.0},
        },
    ]
    assert one == history[:1]
    assert [e.type for e in events] == [
        "fault_raised",
        "fault_raised",
        "fault_cleared",
        "fault_raised",
    ]
    assert events[-1].data["drive"] == "pump1"


async def test_a_store_that_cannot_be_opened_keeps_events_in_memory(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("not a directory")
    config = StorageConfig(path=str(blocker / "events.db"))
    async with running_store(config) as store:
        store.record("command", {"n": 1})
        await store.flush()
        assert [e.data for e in await store.undelivered(10)] == [{"n": 1}]
        assert not store.persistent
    assert any(
        "storage.path" in r.getMessage() and str(blocker) in r.getMessage()
        for r in caplog.records
        if r.levelno == logging.ERROR
    )


async def test_without_mqtt_events_are_history_not_waiting(tmp_path: Path) -> None:
    config = StorageConfig(path=str(tmp_path / "events.db"), max_mb=0.1)
    async with running_store(config, forwarding=False) as store:
        for n in range(2000):
            store.record("command", {"n": n, "note": "x" * 40})
        await store.flush()
        assert await store.undelivered(10) == []
        assert store.stats.events_dropped == 0  # trimmed history is no loss: nobody waited for it
        assert len(await store.recent_events(5)) == 5
