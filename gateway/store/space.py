"""How much of its disk the store may take: `storage.max_mb`, and never more than the disk has.

The disk is shared (the system, its logs, other services). The store counts its own files (the
database, its write-ahead log, the log's index) against both bounds and leaves a reserve free
on the disk: 5 % of it, at least 256 kB, at most 64 MB. The reserve is also what the store needs
for itself to trim and checkpoint (in WAL mode even a delete is written to the log first).

    budget    what the store's files may take in all: max_mb, or what they take now plus what
              is free beyond the reserve, whichever is less
    full      less than half the reserve is free (someone else filled the disk), or the budget
              left is less than `MIN_BUDGET` (trimming a small store to nothing would give back
              next to nothing): nothing is written, events wait in memory until space comes
              back. The store's own writes dip into the reserve only for a moment (the log of
              one transaction, before the trim and the checkpoint that follow it): the other
              half is theirs.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Final

RESERVE_FRACTION: Final = 0.05
RESERVE_MIN: Final = 256 * 1024
RESERVE_MAX: Final = 64 * 1024 * 1024
MIN_BUDGET: Final = 256 * 1024
"""Less room than this (or than max_mb, if smaller) is no room: see `full`."""
FILE_SUFFIXES: Final = ("", "-wal", "-shm")
"""The database and what SQLite keeps beside it in WAL mode."""


@dataclass(frozen=True, slots=True)
class Room:
    own: int
    """What the store's files take now."""
    free: int
    """Free on the disk, for an unprivileged writer."""
    reserve: int
    max_bytes: int

    @property
    def budget(self) -> int:
        return min(self.max_bytes, self.own + self.free - self.reserve)

    @property
    def full(self) -> bool:
        return self.free < self.reserve // 2 or self.budget < min(self.max_bytes, MIN_BUDGET)

    def why_full(self, path: str) -> str:
        return (
            f"storage.path {path}: its disk is full ({self.free // 1024} kB free; the store "
            f"leaves {self.reserve // 1024} kB free and writes nothing below half of that)"
        )


def room(path: str, max_bytes: int) -> Room:
    """The room of the store at `path` on its disk now (a few stat calls)."""
    stat = os.statvfs(Path(path).parent)
    total = stat.f_blocks * stat.f_frsize
    reserve = int(min(RESERVE_MAX, max(RESERVE_MIN, total * RESERVE_FRACTION)))
    return Room(own_bytes(path), stat.f_bavail * stat.f_frsize, reserve, max_bytes)


def own_bytes(path: str) -> int:
    """What the store's files take on the disk (allocated blocks, not apparent sizes)."""
    total = 0
    for suffix in FILE_SUFFIXES:
        try:
            total += os.stat(path + suffix).st_blocks * 512
        except FileNotFoundError:
            continue
    return total
