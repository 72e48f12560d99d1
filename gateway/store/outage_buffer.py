"""The store's outage buffer, as the connections to the broker use it (on the event loop).

    keep       a connection that is away hands over a drive's values of one poll
               (`keep_sample`); returns at once; the writer puts them in the file within
               `SAMPLE_WRITE_S` (one transaction for all that came meanwhile)
    deliver    the connection back reads them in the order polled (`outage_samples`), publishes
               them and marks them delivered (`outage_delivered`: gone from the file)
    bounds     `storage.outage_buffer_mb` and `storage.outage_buffer_hours`
               (`gateway.store.outage_rows`); what went before it was delivered is counted,
               logged (once, then once a minute with the count) and kept as a `Gap` for its
               connection to mark (`outage_gaps`)

`OutageBuffer` is a part of `EventStore` (`events`): the same file, writer and thread.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections import deque
from collections.abc import Mapping
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Final

from gateway.store.database import EventDatabase
from gateway.store.outage_rows import Gap, KeptSample, Sample, Value
from gateway.store.status import StoreStats

log = logging.getLogger(__name__)

SAMPLE_WRITE_S: Final = 1.0
"""Samples wait this long for more (16 drives polled every second are one write a second)."""
MAX_WAITING_SAMPLES: Final = 100_000
"""Samples waiting in memory for a disk that can't take them; the oldest go past it."""
GAP_LOG_EVERY_S: Final = 60.0


class OutageBuffer:
    stats: StoreStats
    path: str
    _db: EventDatabase
    _queued: asyncio.Event
    _executor: ThreadPoolExecutor | None

    def _init_outage_buffer(self) -> None:
        self._samples: deque[Sample] = deque()
        """Kept, not in the file yet: oldest first."""
        self._samples_since: float | None = None
        """When the oldest of them was kept (monotonic)."""
        self._gaps: dict[str, list[Gap]] = {}
        """Per route: what went undelivered, for its connection to mark."""
        self._gaps_logged_at = 0.0
        self._gaps_unlogged = 0

    @property
    def keeps_outages(self) -> bool:
        return self._db.outage.max_bytes > 0

    def keep_sample(
        self, route: str, drive: str, values: Mapping[str, Value], at: float | None = None
    ) -> None:
        """Values of a drive at one poll, polled while `route`'s connection is away."""
        if not self.keeps_outages or not values:
            return
        self._samples.append(Sample(route, drive, time.time() if at is None else at, values))
        self.stats.outage_samples_kept += 1
        if len(self._samples) > MAX_WAITING_SAMPLES:
            dropped = self._samples.popleft()
            self._outage_gaps([Gap(dropped.route, dropped.drive, dropped.time, dropped.time, 1)])
        if self._samples_since is None:
            self._samples_since = time.monotonic()
            self._queued.set()  # the writer wakes when they are due

    async def outage_samples(self, route: str, after: int, limit: int) -> list[KeptSample]:
        """`route`'s samples in the file after id `after`, in the order polled."""
        if self._executor is None:
            return []  # the store is not running (yet, or any more)
        loop = asyncio.get_running_loop()
        rows = self._db.outage
        return await loop.run_in_executor(
            self._executor, lambda: rows.take(self._db.db, route, after, limit)
        )

    def outage_delivered(self, route: str, up_to: int) -> None:
        """`route` published its samples up to id `up_to`: gone from the file (on the store's
        thread, in order; returns at once)."""
        if self._executor is not None:
            rows = self._db.outage
            future = self._executor.submit(lambda: rows.delivered(self._db.db, route, up_to))
            future.add_done_callback(_log_failure)

    def outage_gaps(self, route: str) -> list[Gap]:
        """What went from `route`'s samples before it delivered them, since the last call."""
        return self._gaps.pop(route, [])

    # -- for the writer ------------------------------------------------------------------------

    def _samples_due_in(self) -> float | None:
        if self._samples_since is None:
            return None
        return max(0.0, self._samples_since + SAMPLE_WRITE_S - time.monotonic())

    def _samples_written(self, count: int) -> None:
        for _ in range(count):
            self._samples.popleft()
        self._samples_since = time.monotonic() if self._samples else None

    def _outage_gaps(self, gaps: list[Gap]) -> None:
        if not gaps:
            return
        count = sum(gap.samples for gap in gaps)
        self.stats.outage_samples_dropped += count
        for gap in gaps:
            self._gaps.setdefault(gap.route, []).append(gap)
        self._gaps_unlogged += count
        now = time.monotonic()
        if self._gaps_logged_at and now - self._gaps_logged_at < GAP_LOG_EVERY_S:
            return
        log.warning(
            "store: %d running values polled while the broker was away went before they were "
            "delivered (storage.outage_buffer_mb %g, outage_buffer_hours %g); their gap is "
            "marked (%d since the start)",
            self._gaps_unlogged,
            self._db.outage.max_bytes / 1024 / 1024,
            self._db.outage.max_age_s / 3600,
            self.stats.outage_samples_dropped,
        )
        self._gaps_logged_at = now
        self._gaps_unlogged = 0


def _log_failure(future: Future[None]) -> None:
    exception = future.exception()
    if exception is not None:
        log.error("store: cannot remove delivered outage values: %s (sent again)", exception)
