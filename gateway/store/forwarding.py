"""The MQTT bridge's side of the store: what the broker doesn't have yet, in id order (from the
file, then what waits in memory for a disk that can't take it), marked delivered once the broker
acknowledged it (QoS 1); after a new connection, or a restart, whatever was not marked goes out
again (consumers de-duplicate by `id`).

`StoreForwarding` is the forwarding half of `EventStore` (`events`), which records and writes.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import logging
from collections import deque
from collections.abc import Iterator
from concurrent.futures import Future

from gateway.store.reads import StoreReads
from gateway.store.records import NewEvent, StoredEvent
from gateway.store.status import StoreStats

log = logging.getLogger(__name__)


class StoreForwarding(StoreReads):
    """Forwarding; the journal (`EventStore`) records, writes and keeps what waits in memory."""

    stats: StoreStats
    _waiting: deque[NewEvent]
    _sent_from_memory: set[int]
    _writes_done: int
    _stored: asyncio.Event
    _delivered_up_to: int

    async def undelivered(self, limit: int) -> list[StoredEvent]:
        """The oldest events the broker has not acknowledged yet, in id order: from the file,
        then those waiting in memory (a disk that can't take them)."""
        self._stored.clear()  # before reading: a write finishing after it wakes `wait_stored`
        while True:
            writes = self._writes_done
            events = await self._call(self._db.undelivered, self._delivered_up_to, limit)
            if writes == self._writes_done:
                break  # what waits in memory now is what the file didn't have
            if events:
                return events  # a write ended meanwhile: the rest comes from the file next time
        if len(events) < limit and self._db.forwarding:
            after = max(self._delivered_up_to, events[-1].id if events else 0)
            events += [
                event.stored()
                for event in itertools.islice(self._unsent_waiting(after), limit - len(events))
            ]
        return events

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
        if self._waiting:
            first = self._waiting[0].id  # ids from it on, delivered: sent from memory
            self._sent_from_memory.update(i for i in ids if i >= first)
        if self._executor is not None:
            self._executor.submit(self._db.mark_delivered, ids).add_done_callback(_log_failure)

    def redeliver(self) -> None:
        """A new connection: what was published but never acknowledged goes out again."""
        self._delivered_up_to = 0

    def _unsent_waiting(self, after: int) -> Iterator[NewEvent]:
        for event in self._waiting:
            if event.id > after and event.id not in self._sent_from_memory:
                yield event


def _log_failure(future: Future[None]) -> None:
    exception = future.exception()
    if exception is not None:
        log.error("store: cannot mark events delivered: %s (they will be sent again)", exception)
