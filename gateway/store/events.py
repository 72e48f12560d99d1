"""The event store as the gateway uses it: record at once, write on the store's own thread.

    record     from anywhere on the event loop (poller, buses, commands, reload): the event gets
               its time and its id now and waits in memory (bounded) for the writer; returns at
               once
    writer     one task: takes what waits, writes it in one transaction on the store's thread
               (never on the event loop), holds the size bound, wakes whoever waits for events
    forwarding the MQTT bridge reads what the broker doesn't have yet, in id order, publishes it
               (QoS 1: acknowledged) and then marks it delivered; after a restart whatever was
               not marked goes out again (consumers de-duplicate by `id`): `forwarding`
    tallies    `keep_tally`: a count still growing, written as it grows; the event that
               completes it (`record(..., settles=key)`) replaces it in the same transaction
    reading    `recent_events` and `fault_history`, for MQTT requests and the console: `reads`
    history    `history`: a poll listener averaging each drive's values over a step; each
               finished step's point is written with the next write (`gateway.store.history`);
               `history_points` reads them back for the console's charts (`reads`)
    versions   `add_config_version`, `config_versions`: the configurations applied from the
               console, kept for their diff and a rollback (`reads`)

A disk that is full or failing must not cost the plant its events: what can't be written waits
in memory (at most `max_waiting`, the oldest dropped and counted past it) and goes to the broker
from there, with the id it will have in the file; the writer tries again every second and writes
it, marked delivered where the broker has it, once the disk takes it. A store that can't be
opened (a file of another user, a read-only disk, a damaged file) must not keep the gateway from
serving SCADA either: it says so loudly and keeps the events in memory (`persistent` is False).
Both show in `status()`: /health degraded, naming storage.path, and the console's banner.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import logging
import time
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import replace
from typing import Final, TypeVar

from gateway.errors import DiskFull, StoreError, StoreRefused
from gateway.poller.drive_state import DriveEvent, EventKind, iso_time
from gateway.profile.telemetry import Telemetry
from gateway.settings import StoreSettings
from gateway.store.database import MEMORY, Batch, EventDatabase
from gateway.store.forwarding import StoreForwarding
from gateway.store.history import MAX_WAITING_POINTS, HistoryRecorder
from gateway.store.outage_buffer import OutageBuffer
from gateway.store.outage_rows import OutageRows
from gateway.store.records import (
    EventType,
    HistoryPoint,
    Json,
    NewEvent,
)
from gateway.store.status import StoreState, StoreStats, StoreStatus
from gateway.tasks import ServiceTasks, cancel_and_wait

log = logging.getLogger(__name__)
T = TypeVar("T")

EXPIRE_EVERY_S: Final = 3600.0
RETRY_WRITE_S: Final = 1.0
WRITE_BATCH: Final = 100
"""Events written in one transaction at most: its log must fit in the disk's reserve."""
TALLY_WRITE_S: Final = 0.5
"""A changed tally waits this long for more changes (a SCADA writing every 100 ms is two writes
to the disk a second, not ten): within a second in the store all the same."""
STOP_BUDGET_S: Final = 0.4
DROP_LOG_EVERY_S: Final = 60.0
"""A long outage past the bound drops events at every write: one log line a minute says so."""
SNAPSHOT_LEAVES_OUT: Final = frozenset(
    {"fault_code", "fault_name", "fault_description", "last_seen"}
)


class EventStore(StoreForwarding, OutageBuffer):
    """The journal: events recorded on the event loop, written on the store's thread, forwarded
    to the broker; what it reads back is `StoreReads`'."""

    def __init__(self, settings: StoreSettings, tasks: ServiceTasks) -> None:
        self.settings = settings
        self.path = settings.path
        self._seen_since_start: set[str] = set()
        self._faults_to_close: list[tuple[str, float]] = []
        self.tasks = tasks
        self.stats = StoreStats()
        self._db = EventDatabase(
            self.path,
            int(settings.max_mb * 1024 * 1024),
            settings.max_age_days * 86400,
            settings.forwarding,
            settings.history_days * 86400,
            settings.shared_path,
            OutageRows(
                int(settings.outage_buffer_mb * 1024 * 1024), settings.outage_buffer_hours * 3600
            ),
        )
        self._init_outage_buffer()
        self.history = HistoryRecorder(self._keep_history, settings.history_step_s)
        """The poller's listener for the history of polled values (the application adds it)."""
        self.history.enabled = settings.history_days > 0
        self._history: deque[HistoryPoint] = deque(maxlen=MAX_WAITING_POINTS)
        """History points not in the file yet, oldest first."""
        self._waiting: deque[NewEvent] = deque()
        """Recorded, not in the file yet: oldest first, ids increasing."""
        self._sent_from_memory: set[int] = set()
        """Ids of waiting events the broker acknowledged: written as delivered."""
        self._tallies: dict[str, NewEvent] = {}
        """Tallies changed since the last write, by key."""
        self._tallies_since: float | None = None
        """When the oldest unwritten change of a tally was made (monotonic)."""
        self._max_waiting = settings.max_waiting
        self._next_id = 1
        self._writes_done = 0
        """Counts the writes finished: a read of the file that a write overtook is read again."""
        self._memory_only: str | None = None
        """Why storage.path could not be opened (the events are in memory only)."""
        self._cannot_write: str | None = None
        """Why the last write failed (a full or failing disk); None while writing."""
        self._queued = asyncio.Event()
        self._stored = asyncio.Event()
        self._written = asyncio.Condition()
        self._closing = False
        self._executor: ThreadPoolExecutor | None = None
        self._writer: asyncio.Task[None] | None = None
        self._delivered_up_to = 0
        """Events up to this id were acknowledged by the broker (this run: no re-query)."""
        self.forwarding = asyncio.Lock()
        """Held by the one forwarding the events (`forward_stored`): two would send each twice."""
        self._drops_logged_at = 0.0
        self._drops_unlogged = 0

    def update_bounds(self, settings: StoreSettings) -> None:
        """A reload: max_mb, max_age_days and the history's from now on (the path, forwarding
        and the memory queue stay until a restart)."""
        self.settings = replace(
            self.settings,
            max_mb=settings.max_mb,
            max_age_days=settings.max_age_days,
            history_days=settings.history_days,
            history_step_s=settings.history_step_s,
            outage_buffer_mb=settings.outage_buffer_mb,
            outage_buffer_hours=settings.outage_buffer_hours,
        )
        self._db.max_bytes = int(settings.max_mb * 1024 * 1024)
        self._db.max_age_s = settings.max_age_days * 86400
        self._db.history_max_age_s = settings.history_days * 86400
        self._db.outage.max_bytes = int(settings.outage_buffer_mb * 1024 * 1024)
        self._db.outage.max_age_s = settings.outage_buffer_hours * 3600
        self.history.enabled = settings.history_days > 0
        self.history.step_s = settings.history_step_s

    @property
    def persistent(self) -> bool:
        return self._db.persistent

    def status(self) -> StoreStatus:
        if self._memory_only is not None:
            state, reason = StoreState.MEMORY_ONLY, self._memory_only
        elif self._cannot_write is not None:
            state, reason = StoreState.CANNOT_WRITE, self._cannot_write
        else:
            state, reason = StoreState.WRITING, None
        return StoreStatus(state, self.path, reason, len(self._waiting))

    # -- recording: on the event loop, returns at once ------------------------------------------

    def record(
        self,
        type: str,
        data: Json,
        *,
        drive: str | None = None,
        at: float | None = None,
        snapshot: Json | None = None,
        settles: str | None = None,
    ) -> None:
        """`settles`: the key of the tally (`keep_tally`) this event completes."""
        self.stats.events_recorded += 1
        at = time.time() if at is None else at
        event = NewEvent(str(type), at, data, drive, snapshot, self._take_id(), settles)
        self._waiting.append(event)
        if self._db.forwarding:
            self.stats.undelivered += 1
        if settles is not None:
            self._tallies.pop(settles, None)
        while len(self._waiting) > self._max_waiting:
            # The disk is failing: the newest tell the current story.
            self._forget(self._waiting.popleft())
        self._queued.set()
        if self._cannot_write is not None:
            self._stored.set()  # not in the file soon: the broker gets it from memory

    def keep_tally(
        self, key: str, type: str, data: Json, *, drive: str | None = None, at: float
    ) -> None:
        """A count still growing (a minute's SCADA writes) as it is now: written with the next
        write (within the second), so a killed gateway loses none of it; at the next start a
        tally left in the file becomes an event. `record(..., settles=key)` completes it."""
        if not self._tallies:
            self._tallies_since = time.monotonic()
            self._queued.set()  # the writer wakes when it is due
        self._tallies[key] = NewEvent(str(type), at, data, drive)

    def _keep_history(self, point: HistoryPoint) -> None:
        """A finished history step: written with the next write (the oldest dropped past
        `MAX_WAITING_POINTS` while the disk can't take them)."""
        self._history.append(point)
        self._queued.set()

    def record_drive_event(self, event: DriveEvent, snapshot: Telemetry | None = None) -> None:
        data: Json = {"drive": event.drive, **event.data, "time": iso_time(event.at)}
        self.record(event.kind.value, data, drive=event.drive, at=event.at, snapshot=snapshot)

    # -- PollListener: the poller's events ------------------------------------------------------

    def state_updated(self, drive: str, telemetry: Telemetry) -> None:
        if drive in self._seen_since_start:
            return
        self._seen_since_start.add(drive)
        if telemetry.get("fault_code") == 0:
            # The first state since start shows no fault: one left open in the history cleared
            # while the gateway was down (no fault_cleared event was seen for it).
            self._faults_to_close.append((drive, time.time()))
            self._queued.set()

    def availability_changed(self, drive: str, online: bool) -> None:
        pass  # drive_online / drive_offline come as events

    def drive_event(self, event: DriveEvent) -> None:
        snapshot = None
        if event.kind is EventKind.FAULT_RAISED:
            snapshot = {k: v for k, v in event.snapshot.items() if k not in SNAPSHOT_LEAVES_OUT}
        self.record_drive_event(event, snapshot)

    # -- the buses' ports -------------------------------------------------------------------------

    def port_changed(self, bus: str, port: str, lost: bool, reason: str) -> None:
        data: Json = {"bus": bus, "port": port}
        if lost:
            data["reason"] = reason
        self.record(EventType.PORT_LOST if lost else EventType.PORT_BACK, data)

    # -- lifecycle -------------------------------------------------------------------------------

    async def start(self) -> None:
        self._executor = ThreadPoolExecutor(1, thread_name_prefix="store")
        try:
            migrated = await self._call(self._db.open)
        except StoreRefused:
            self._executor.shutdown(wait=False)
            self._executor = None
            raise
        except StoreError as exc:
            self._memory_only = (
                f"storage.path: cannot open the store ({exc}); events are kept in memory only, "
                "a restart loses them (the file and its directory must be the service user's, "
                "on a writable disk)"
            )
            log.error("%s", self._memory_only)
            self._db.path = MEMORY
            migrated = await self._call(self._db.open)
        self.path = self._db.path if self.persistent else self.path  # the file it chose
        if self._db.note is not None:
            log.warning("%s", self._db.note)
        if self.persistent and migrated and migrated[0] > 1:
            log.info("store %s: schema migrated to %d (ran %s)", self.path, migrated[-1], migrated)
        settled = await self._call(self._db.settle_tallies)
        if settled:
            log.info("store %s: %d tallies left by the last run recorded", self.path, settled)
        self._renumber(await self._call(self._db.next_id))
        self.stats.undelivered = await self._call(self._db.undelivered_count) + (
            len(self._waiting) if self._db.forwarding else 0
        )
        dropped = await self._call(self._db.expire, time.time())
        self._dropped(dropped, f"older than storage.max_age_days ({self.settings.max_age_days:g})")
        if self.stats.undelivered:
            log.info("store %s: %d events wait for the broker", self.path, self.stats.undelivered)
        self._writer = self.tasks.start("store:writer", self._write_forever())

    async def stop(self) -> None:
        """Write what waits, then close the database (a clean close checkpoints the WAL)."""
        self.history.finish()
        self._closing = True
        self._queued.set()
        if self._writer is not None:
            done, _ = await asyncio.wait({self._writer}, timeout=STOP_BUDGET_S)
            if not done:
                log.error("store: %d events not written at stop", len(self._waiting))
                await cancel_and_wait(self._writer, STOP_BUDGET_S)
            self._writer = None
        if self._executor is not None:
            with contextlib.suppress(StoreError):
                await self._call(self._db.close)
            self._executor.shutdown(wait=False)
            self._executor = None

    async def flush(self) -> None:
        """Until every event recorded so far is written (or a write failed: the disk)."""
        if self._tallies:
            self._tallies_since = -TALLY_WRITE_S  # due now
        if self._samples:
            self._samples_since = -TALLY_WRITE_S
        if self._tallies or self._samples:
            self._queued.set()
        async with self._written:
            await self._written.wait_for(
                lambda: (
                    not (self._waiting or self._tallies or self._history or self._samples)
                    or self._cannot_write is not None
                )
            )

    # -- inside ----------------------------------------------------------------------------------

    async def _write_forever(self) -> None:
        next_expiry = time.monotonic() + EXPIRE_EVERY_S
        while True:
            due = self._due_in()
            if due is None and self._closing:
                return
            if due != 0.0:
                self._queued.clear()
                wait_s = next_expiry - time.monotonic()
                if due is not None:
                    wait_s = min(wait_s, due)
                with contextlib.suppress(TimeoutError):
                    async with asyncio.timeout(max(0.0, wait_s)):
                        await self._queued.wait()
            if time.monotonic() >= next_expiry:
                next_expiry = time.monotonic() + EXPIRE_EVERY_S
                await self._expire()
            await self._close_faults()
            if self._due_in() != 0.0:
                continue
            if not await self._write():
                if self._closing:
                    log.error("store: %d events not written at stop", len(self._waiting))
                    return
                await asyncio.sleep(RETRY_WRITE_S)

    async def _write(self) -> bool:
        """Write what waits in one transaction; False if the disk didn't take it."""
        events = tuple(itertools.islice(self._waiting, WRITE_BATCH))
        history = tuple(self._history)
        samples = tuple(self._samples)
        batch = Batch(
            events, frozenset(self._sent_from_memory), dict(self._tallies), history, samples
        )
        try:
            appended = await self._call(self._db.append, batch)
        except Exception as exc:  # DiskFull, sqlite3.Error, OSError: a full or failing disk
            self._write_failed(exc)
            async with self._written:
                self._written.notify_all()  # a flush waits no longer
            return False
        written = {id(point) for point in history}
        while self._history and id(self._history[0]) in written:
            self._history.popleft()
        last = batch.events[-1].id if batch.events else 0
        while self._waiting and self._waiting[0].id <= last:
            self._sent_from_memory.discard(self._waiting.popleft().id)
        for key, tally in batch.tallies.items():
            if self._tallies.get(key) is tally:
                del self._tallies[key]  # not changed meanwhile
        self._tallies_since = time.monotonic() if self._tallies else None
        self._samples_written(len(samples))
        self._outage_gaps(appended.gaps)
        self._writes_done += 1
        self.stats.stored += len(batch.events)
        if self._cannot_write is not None:
            log.warning(
                "store %s: writing again; %d events that waited in memory are in the file",
                self.path,
                len(batch.events),
            )
            self._cannot_write = None
        self._dropped(appended.dropped, self._bound_reached(appended.bound))
        self._stored.set()
        async with self._written:
            self._written.notify_all()
        return True

    def _write_failed(self, exc: Exception) -> None:
        self.stats.write_failures += 1
        reason = str(exc) if isinstance(exc, DiskFull) else f"storage.path {self.path}: {exc}"
        first = self._cannot_write is None
        self._cannot_write = reason
        if first:
            log.error(
                "store: cannot write events: %s; they wait in memory (at most %d) and go to the "
                "broker from there; retrying every %g s",
                reason,
                self._max_waiting,
                RETRY_WRITE_S,
            )
            self._stored.set()  # the publisher takes them from memory now
        else:
            log.debug("store: still cannot write: %s", reason)
        if self._executor is not None:
            # What the write-ahead log holds goes into the file and gives its space back.
            self._executor.submit(self._db.give_back).add_done_callback(_ignore)

    def _due_in(self) -> float | None:
        """Seconds until something is to be written (0.0: now), None with nothing to write."""
        if self._waiting or self._history or ((self._tallies or self._samples) and self._closing):
            return 0.0
        due = [self._samples_due_in()]
        if self._tallies_since is not None and self._tallies:
            due.append(max(0.0, self._tallies_since + TALLY_WRITE_S - time.monotonic()))
        return min((d for d in due if d is not None), default=None)

    def _bound_reached(self, bound: int) -> str:
        if bound >= self._db.max_bytes:
            return f"storage.max_mb ({self.settings.max_mb:g}) reached"
        return f"its disk has room for {bound / 1024 / 1024:.1f} MB only (less than storage.max_mb)"

    def _renumber(self, next_id: int) -> None:
        """Ids from the file's sequence on; events recorded before start take the first."""
        self._next_id = next_id
        waiting = [replace(event, id=self._take_id()) for event in self._waiting]
        self._waiting = deque(waiting)

    def _take_id(self) -> int:
        self._next_id += 1
        return self._next_id - 1

    def _forget(self, event: NewEvent) -> None:
        """An event pushed out of memory past `max_waiting` before the file had it."""
        if event.id in self._sent_from_memory:
            self._sent_from_memory.discard(event.id)
            self.stats.events_not_stored += 1  # the broker has it; the file never will
            return
        self._dropped(1, "waiting in memory while storage.path could not be written")

    async def _close_faults(self) -> None:
        while self._faults_to_close:
            drive, at = self._faults_to_close.pop(0)
            try:
                closed = await self._call(self._db.close_open_faults, drive, at)
            except Exception as exc:  # sqlite3.Error, OSError: the history stays as it was
                log.warning("store %s: fault history of %s not updated: %s", self.path, drive, exc)
                continue
            if closed:
                log.info(
                    "%s: %d fault(s) cleared while the gateway was down, closed now", drive, closed
                )

    async def _expire(self) -> None:
        try:
            dropped = await self._call(self._db.expire, time.time())
        except Exception as exc:
            log.error("store %s: cannot remove old events: %s", self.path, exc)
            return
        self._dropped(dropped, f"older than storage.max_age_days ({self.settings.max_age_days:g})")

    def _dropped(self, count: int, why: str) -> None:
        if not count:
            return
        self.stats.events_dropped += count
        if self._db.forwarding:
            self.stats.undelivered = max(0, self.stats.undelivered - count)
        self._drops_unlogged += count
        now = time.monotonic()
        if self._drops_logged_at and now - self._drops_logged_at < DROP_LOG_EVERY_S:
            return
        log.warning(
            "store: %d events the broker never had were dropped, oldest first: %s "
            "(%d dropped since the start)",
            self._drops_unlogged,
            why,
            self.stats.events_dropped,
        )
        self._drops_logged_at = now
        self._drops_unlogged = 0


def _ignore(future: Future[None]) -> None:
    """Giving space back is worth trying; with the disk full it may fail too."""
    future.exception()
