"""Whether the store keeps events on disk now, as /health, `healthcheck` and the console say it.

writing        events are written to storage.path (the normal case)
cannot_write   the disk is full or failing: events wait in memory (bounded) and go to the
               broker from there; written once the disk takes them again, without a restart
memory_only    storage.path could not be opened (owned by another user, a read-only disk, a
               damaged file): events are kept in memory only, a restart loses them
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
