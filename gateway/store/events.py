"""The event store as the gateway uses it: record at once, write on the store's own thread.

    record     from anywhere on the event loop (poller, buses, commands, reload): the event gets
               its time now and waits in memory (bounded) for the writer; returns at once
    writer     one task: takes what waits, writes it in one transaction on the store's thread
               (never on the event loop), holds the size bound, wakes whoever waits for events
    forwarding the MQTT bridge reads what the broker doesn't have yet, in id order, publishes it
               (QoS 1: acknowledged) and then marks it delivered; after a restart whatever was
               not marked goes out again (consumers de-duplicate by `id`)
    reading    `recent_events` and `fault_history`, for MQTT requests and the console

A store that can't be opened (a read-only disk, a corrupt file) must not keep the gateway from
serving SCADA: it says so loudly, once, and keeps the events in memory (`persistent` is False, a
metric shows it), where they still wait out a broker outage but not a restart.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, replace
from typing import Final, TypeVar

from gateway.errors import StoreError
from gateway.poller.drive_state import DriveEvent, EventKind, iso_time
from gateway.profile.telemetry import Telemetry
from gateway.settings import StoreSettings
from gateway.store.database import MEMORY, EventDatabase
from gateway.store.records import EventType, FaultRecord, Json, NewEvent, StoredEvent
from gateway.tasks import ServiceTasks, cancel_and_wait

log = logging.getLogger(__name__)
T = TypeVar("T")

EXPIRE_EVERY_S: Final = 3600.0
RETRY_WRITE_S: Final = 1.0
STOP_BUDGET_S: Final = 0.4
DROP_LOG_EVERY_S: Final = 60.0
"""A long outage past the bound drops events at every write: one log line a minute says so."""
SNAPSHOT_LEAVES_OUT: Final = frozenset(
    {"fault_code", "fault_name", "fault_description", "last_seen"}
)


@dataclass(slots=True)
class StoreStats:
    events_recorded: int = 0
    stored: int = 0
    events_delivered: int = 0
    events_dropped: int = 0
    """Events removed (size or age bound, or memory while the disk failed) before the broker
    had them."""
    write_failures: int = 0
    undelivered: int = 0
    """Stored, and not yet acknowledged by the broker."""


class EventStore:
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
        )
        self._waiting: deque[NewEvent] = deque()
        self._max_waiting = settings.max_waiting
        self._queued = asyncio.Event()
        self._stored = asyncio.Event()
        self._written = asyncio.Condition()
        self._closing = False
        self._executor: ThreadPoolExecutor | None = None
        self._writer: asyncio.Task[None] | None = None
        self._delivered_up_to = 0
        """Events up to this id were acknowledged by the broker (this run: no re-query)."""
        self._drops_logged_at = 0.0
        self._drops_unlogged = 0

    def update_bounds(self, settings: StoreSettings) -> None:
        """A reload: max_mb and max_age_days from now on (the path, forwarding and the memory
        queue stay until a restart)."""
        self.settings = replace(
            self.settings, max_mb=settings.max_mb, max_age_days=settings.max_age_days
        )
        self._db.max_bytes = int(settings.max_mb * 1024 * 1024)
        self._db.max_age_s = settings.max_age_days * 86400

    @property
    def persistent(self) -> bool:
        return self._db.persistent

    # -- recording: on the event loop, returns at once ------------------------------------------

    def record(
        self,
        type: str,
        data: Json,
        *,
        drive: str | None = None,
        at: float | None = None,
        snapshot: Json | None = None,
    ) -> None:
        self.stats.events_recorded += 1
        event = NewEvent(str(type), time.time() if at is None else at, data, drive, snapshot)
        self._waiting.append(event)
        while len(self._waiting) > self._max_waiting:
            self._waiting.popleft()  # the disk is failing: the newest tell the current story
            self._dropped(1, "in memory while the store could not be written", stored=False)
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
            await self._call(self._db.open)
        except StoreError as exc:
            log.error(
                "storage.path: cannot open the store (%s); events are kept in memory only, "
                "a restart loses them",
                exc,
            )
            self._db.path = MEMORY
            await self._call(self._db.open)
        self.stats.undelivered = await self._call(self._db.undelivered_count)
        dropped = await self._call(self._db.expire, time.time())
        self._dropped(dropped, f"older than storage.max_age_days ({self.settings.max_age_days:g})")
        if self.stats.undelivered:
            log.info("store %s: %d events wait for the broker", self.path, self.stats.undelivered)
        self._writer = self.tasks.start("store:writer", self._write_forever())

    async def stop(self) -> None:
        """Write what waits, then close the database (a clean close checkpoints the WAL)."""
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
        """Until every event recorded so far is written (or dropped, the disk failing)."""
        async with self._written:
            await self._written.wait_for(lambda: not self._waiting)

    # -- forwarding: the MQTT bridge's side ----------------------------------------------------

    async def undelivered(self, limit: int) -> list[StoredEvent]:
        """The oldest events the broker has not acknowledged yet, in id order."""
        self._stored.clear()  # before reading: a write finishing after it wakes `wait_stored`
        return await self._call(self._db.undelivered, self._delivered_up_to, limit)

    async def wait_stored(self, timeout_s: float) -> None:
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(timeout_s):
                await self._stored.wait()

    def delivered(self, ids: list[int]) -> None:
        """The broker acknowledged these: marked on the store's thread, in order; returns at once
        (so that a cancelled publisher still gets what it sent marked)."""
        if not ids:
            return
        self._delivered_up_to = max(self._delivered_up_to, *ids)
        self.stats.events_delivered += len(ids)
        self.stats.undelivered = max(0, self.stats.undelivered - len(ids))
        if self._executor is not None:
            self._executor.submit(self._db.mark_delivered, ids).add_done_callback(_log_failure)

    def redeliver(self) -> None:
        """A new connection: what was published but never acknowledged goes out again."""
        self._delivered_up_to = 0

    # -- reading: MQTT requests, the console ------------------------------------------------------

    async def recent_events(self, limit: int, drive: str | None = None) -> list[StoredEvent]:
        """The newest `limit` events (of `drive`), newest first."""
        return await self._call(self._db.recent, limit, drive)

    async def fault_history(self, drive: str, limit: int) -> list[FaultRecord]:
        """The newest `limit` faults of `drive`, newest first."""
        return await self._call(self._db.faults, drive, limit)

    async def size_bytes(self) -> int:
        return await self._call(self._db.file_bytes)

    # -- inside ----------------------------------------------------------------------------------

    async def _call(self, function: Callable[..., T], *args: object) -> T:
        if self._executor is None:
            raise StoreError(f"{self.path}: the store is not running")
        loop = asyncio.get_running_loop()
        return await loop.run_in_executor(self._executor, function, *args)

    async def _write_forever(self) -> None:
        next_expiry = time.monotonic() + EXPIRE_EVERY_S
        failures = 0
        while True:
            if not self._waiting:
                if self._closing:
                    return
                self._queued.clear()
                with contextlib.suppress(TimeoutError):
                    async with asyncio.timeout(max(0.0, next_expiry - time.monotonic())):
                        await self._queued.wait()
            if time.monotonic() >= next_expiry:
                next_expiry = time.monotonic() + EXPIRE_EVERY_S
                await self._expire()
            await self._close_faults()
            if not self._waiting:
                continue
            batch = list(self._waiting)
            try:
                appended = await self._call(self._db.append, batch)
            except Exception as exc:  # sqlite3.Error, OSError: a full or failing disk
                failures += 1
                self.stats.write_failures += 1
                level = logging.ERROR if failures == 1 else logging.DEBUG
                log.log(level, "store %s: cannot write events: %s; retrying", self.path, exc)
                if self._closing:
                    return
                await asyncio.sleep(RETRY_WRITE_S)
                continue
            if failures:
                log.info("store %s: writing again after %d failures", self.path, failures)
                failures = 0
            for _ in batch:
                self._waiting.popleft()  # only now: a failed write keeps them waiting
            self.stats.stored += len(batch)
            if self._db.forwarding:
                self.stats.undelivered += len(batch)
            self._dropped(appended.dropped, f"storage.max_mb ({self.settings.max_mb:g}) reached")
            self._stored.set()
            async with self._written:
                self._written.notify_all()

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

    def _dropped(self, count: int, why: str, stored: bool = True) -> None:
        if not count:
            return
        self.stats.events_dropped += count
        if stored:
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


def _log_failure(future: Future[None]) -> None:
    exception = future.exception()
    if exception is not None:
        log.error("store: cannot mark events delivered: %s (they will be sent again)", exception)
