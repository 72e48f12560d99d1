"""Whether the store keeps events on disk now, as /health, `healthcheck` and the console say it.

writing        events are written to storage.path (the normal case)
cannot_write   the disk is full or failing: events wait in memory (bounded) and go to the
               broker from there; written once the disk takes them again, without a restart
memory_only    storage.path could not be opened (owned by another user, a read-only disk, a
               damaged file): events are kept in memory only, a restart loses them

`StoreStats` are the store's counters since the start, for /metrics (`store.metrics`).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from typing import Any


class StoreState(StrEnum):
    WRITING = "writing"
    CANNOT_WRITE = "cannot_write"
    MEMORY_ONLY = "memory_only"


@dataclass(frozen=True, slots=True)
class StoreStatus:
    state: StoreState
    path: str
    reason: str | None
    """Why events are not on disk, naming storage.path; None while writing."""
    events_in_memory: int
    """Recorded events not (yet) on disk."""

    @property
    def ok(self) -> bool:
        return self.state is StoreState.WRITING

    def as_json(self) -> dict[str, Any]:
        return {
            "state": str(self.state),
            "path": self.path,
            "reason": self.reason,
            "events_in_memory": self.events_in_memory,
        }


@dataclass(slots=True)
class StoreStats:
    events_recorded: int = 0
    stored: int = 0
    events_delivered: int = 0
    events_dropped: int = 0
    """Events removed (size or age bound, or memory while the disk failed) before the broker
    had them."""
    write_failures: int = 0
    events_not_stored: int = 0
    """Events pushed out of memory while the disk could not take them, though the broker had
    them: gone from the history only."""
    undelivered: int = 0
    """Recorded (on disk or waiting in memory), and not yet acknowledged by the broker."""
    outage_samples_kept: int = 0
    """Drives' values of one poll kept while a connection to the broker was away."""
    outage_samples_dropped: int = 0
    """Of those, removed by the outage buffer's bounds before they were delivered."""
