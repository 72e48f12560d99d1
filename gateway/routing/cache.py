"""The poll cache: the last value polled of each register, with when the poll was issued.

The router owns it (`gateway.routing.router`): it stores every poll's answer here and may answer a
SCADA read from it when every register asked for is fresh enough (`cache_max_age_ms` of that
drive), so many readers of the same values cost no bus time at all.

Two rules keep it from ever answering with a value the drive no longer has:
- a value is as old as the moment its poll was *issued* (queued), not answered: the drive may
  have changed in between, never after;
- a write through the gateway bumps the drive's write generation and forgets what the drive said,
  when it goes out and again when it is answered; a poll issued before the write is answered (it
  may carry the old value) is not stored.
Polls themselves never read the cache: a poll is how the cache learns what the drive says.
"""

from __future__ import annotations

import time
from collections.abc import Sequence


class RegisterCache:
    def __init__(self) -> None:
        # drive -> register -> (value, monotonic time the poll was issued)
        self._values: dict[str, dict[int, tuple[int, float]]] = {}
        self._generations: dict[str, int] = {}
        self.hits = 0
        self.misses = 0
        self.discarded = 0

    def generation(self, drive: str) -> int:
        """The drive's write generation: take it when issuing a poll, hand it to `store`."""
        return self._generations.get(drive, 0)

    def store(
        self,
        drive: str,
        start: int,
        values: Sequence[int],
        issued_at: float,
        generation: int,
    ) -> bool:
        """Keep a poll's values, unless a write went out after the poll was issued."""
        if generation != self._generations.get(drive, 0):
            self.discarded += 1
            return False
        registers = self._values.setdefault(drive, {})
        for offset, value in enumerate(values):
            registers[start + offset] = (value, issued_at)
        return True

    def invalidate(self, drive: str) -> None:
        """A write goes to the drive: forget all it said, and refuse polls issued before it.

        All of it, not just the written registers: a control word changes the state words, a
        parameter changes running values, a RAM twin (8xxxH) changes its parameter.
        """
        self._generations[drive] = self._generations.get(drive, 0) + 1
        self._values.pop(drive, None)

    def forget(self, drive: str) -> None:
        """The drive stopped answering: nothing it said before may be served as current."""
        self._values.pop(drive, None)

    def lookup(
        self, drive: str, start: int, count: int, max_age_s: float, now: float | None = None
    ) -> list[int] | None:
        """All `count` values from `start` if each was polled within `max_age_s`, else None."""
        registers = self._values.get(drive)
        oldest = (time.monotonic() if now is None else now) - max_age_s
        values = []
        for register in range(start, start + count):
            entry = registers.get(register) if registers else None
            if entry is None or entry[1] < oldest:
                self.misses += 1
                return None
            values.append(entry[0])
        self.hits += 1
        return values
