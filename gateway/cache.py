"""The poll cache: the last value read of each polled register, with when it was read.

The poller stores every poll result here; the router may answer a SCADA read from it when every
register asked for is fresh enough (`cache_max_age_ms` of that drive), so many readers of the same
values cost no bus time at all.
"""

from __future__ import annotations

import time
from collections.abc import Sequence


class RegisterCache:
    def __init__(self) -> None:
        # drive -> register -> (value, monotonic time read)
        self._values: dict[str, dict[int, tuple[int, float]]] = {}
        self.hits = 0
        self.misses = 0

    def store(self, drive: str, start: int, values: Sequence[int], at: float | None = None) -> None:
        read_at = time.monotonic() if at is None else at
        registers = self._values.setdefault(drive, {})
        for offset, value in enumerate(values):
            registers[start + offset] = (value, read_at)

    def invalidate(self, drive: str, start: int, count: int) -> None:
        """A write went to these registers: the cached values are no longer the drive's."""
        registers = self._values.get(drive)
        if registers:
            for register in range(start, start + count):
                registers.pop(register, None)

    def lookup(
        self, drive: str, start: int, count: int, max_age_s: float, now: float | None = None
    ) -> list[int] | None:
        """All `count` values from `start` if each was read within `max_age_s`, else None."""
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
