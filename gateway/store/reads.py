"""What the store's file answers, read on the store's one thread (never on the event loop):
the recent events, a drive's faults, the history of polled values over a window (with the
points still waiting for the disk), the configuration versions kept, the file's size.

`StoreReads` is the reading half of `EventStore` (`events`), which adds the journal: recording,
writing, forwarding. The MQTT requests, the console and the poller read through it.
"""

from __future__ import annotations

import asyncio
import time
from collections import deque
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

from gateway.errors import StoreError
from gateway.settings import StoreSettings
from gateway.store import counters, history_queries
from gateway.store.database import EventDatabase
from gateway.store.history import HistoryRecorder, span_for
from gateway.store.records import ConfigVersion, FaultRecord, HistoryPoint, StoredEvent

T = TypeVar("T")


class StoreReads:
    """Reads of the file; the journal (`EventStore`) owns the file, its thread and what waits."""

    settings: StoreSettings
    path: str
    history: HistoryRecorder
    _db: EventDatabase
    _history: deque[HistoryPoint]
    """History points not in the file yet, oldest first."""
    _executor: ThreadPoolExecutor | None

    @property
    def history_step_s(self) -> float:
        return self.history.step_s

    @property
    def history_days(self) -> float:
        return self.settings.history_days

    async def recent_events(
        self,
        limit: int,
        drive: str | None = None,
        *,
        types: Sequence[str] = (),
        since: float | None = None,
        until: float | None = None,
    ) -> list[StoredEvent]:
        """The newest `limit` events (of `drive`, of one of `types`, from `since` to before
        `until`, in epoch seconds), newest first."""
        return await self._call(self._db.recent, limit, drive, tuple(types), since, until)

    async def fault_history(self, drive: str, limit: int) -> list[FaultRecord]:
        """The newest `limit` faults of `drive`, newest first."""
        return await self._call(self._db.faults, drive, limit)

    async def open_faults(self) -> dict[str, int]:
        """Drive → its fault still open in the fault history: what the drives were in when
        the last run stopped. Empty when the store can't say (it isn't running)."""
        try:
            return await self._call(self._db.open_faults)
        except StoreError:
            return {}

    async def history_points(
        self, drive: str, since: float, until: float
    ) -> list[tuple[float, dict[str, float | str]]]:
        """`drive`'s history points from `since` to before `until` (epoch s), oldest first;
        those still waiting for the disk included."""
        stored = await self._query(history_queries.points, drive, since, until)
        return self._with_waiting(dict(stored), drive, since, until, 0.0)

    async def history_window(
        self, drive: str, since: float, until: float, max_points: int
    ) -> tuple[float, list[tuple[float, dict[str, float | str]]]]:
        """`history_points`, at most `max_points` of them (about): the points as they are when
        the window has no more, else reduced in the database to one a span (`span_for`);
        the time one point stands for, and the points. A point still waiting for the disk
        stands for its span where the disk has nothing of it."""
        step_s = self.history_step_s
        rows = await self._query(history_queries.count, drive, since, until)
        if rows <= max_points:
            return step_s, await self.history_points(drive, since, until)
        span_s = span_for(until - since, step_s, max_points)
        reduced = await self._query(history_queries.reduced, drive, since, until, span_s)
        return span_s, self._with_waiting(dict(reduced), drive, since, until, span_s)

    def _with_waiting(
        self,
        points: dict[float, dict[str, float | str]],
        drive: str,
        since: float,
        until: float,
        span_s: float,
    ) -> list[tuple[float, dict[str, float | str]]]:
        for point in list(self._history):
            if point.drive != drive or not since <= point.time < until:
                continue
            if not span_s:  # as the write will merge them
                points[point.time] = {**points.get(point.time, {}), **point.values}
            else:
                points.setdefault(point.time - point.time % span_s, dict(point.values))
        return sorted(points.items(), key=lambda point: point[0])

    async def history_rows(self) -> int:
        return await self._query(history_queries.rows)

    async def add_config_version(self, user: str, text: str, note: str) -> int:
        """Keep a configuration's text at once (not through the writer: the caller must know it
        is kept before applying it); its version number. `StoreError` if it can't be."""
        try:
            return await self._call(self._db.add_config_version, time.time(), user, text, note)
        except StoreError:
            raise
        except Exception as exc:  # sqlite3.Error, OSError: a full or failing disk
            raise StoreError(f"storage.path {self.path}: {exc}") from exc

    async def count_on(self, key: str, modulo: int, after: int | None = None) -> int:
        """The counter `key` one further (than `after`, if given), kept in the file at once (not
        through the writer: the caller must know it is kept before using it). `StoreError` if
        it can't be; in a store kept in memory only it starts from 0 at every start."""
        try:
            return await self._query(counters.count_on, key, modulo, after)
        except StoreError:
            raise
        except Exception as exc:  # sqlite3.Error, OSError: a full or failing disk
            raise StoreError(f"storage.path {self.path}: {exc}") from exc

    async def remove_config_version(self, number: int) -> None:
        await self._call(self._db.remove_config_version, number)

    async def config_versions(self) -> list[ConfigVersion]:
        return await self._call(self._db.config_versions)

    async def size_bytes(self) -> int:
        return await self._call(self._db.file_bytes)

    async def _call(self, function: Callable[..., T], *args: object) -> T:
        if self._executor is None:
            raise StoreError(f"{self.path}: the store is not running")
        loop = asyncio.get_running_loop()
        return await loop.run_in_executor(self._executor, function, *args)

    async def _query(self, query: Callable[..., T], *args: object) -> T:
        """`query(connection, *args)` on the store's thread (the connection taken there)."""
        return await self._call(lambda: query(self._db.db, *args))
