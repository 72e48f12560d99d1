"""What some devices on a real line do that a well-behaved drive doesn't: frame only the function
codes they know, stall, drop requests.

- **Knows only some function codes**: a device built on libmodbus (many meters and I/O modules)
  frames only the function codes it implements; anything else it takes for a frame with a wrong
  CRC and stays silent. No exception 01H comes back, so a master that depends on one (to probe,
  to resynchronise) never hears from such a device.
- **Stalls**: a device busy with something else (an EEPROM write, a firmware task, a process
  stopped for a moment) takes requests in and answers them once it carries on, in order.
- **Drops**: a request lost to noise at the device's end, never answered.
- **Refuses**: a device that answers every request with one exception code for a while: a
  standard device busy with a long command answers 06H (server device busy).
"""

from __future__ import annotations

import random
from collections.abc import Iterable


class DeviceQuirks:
    """The quirks of each address on one simulated line. Called with the line's lock held."""

    def __init__(self, seed: int = 0) -> None:
        self._known: dict[int, frozenset[int]] = {}
        self._stalled_until: dict[int, float] = {}
        self._drop_rate: dict[int, float] = {}
        self._refusing: dict[int, int] = {}
        self._random = random.Random(seed)
        self.dropped = 0
        self.unframed = 0

    def know_only(self, address: int, functions: Iterable[int] | None) -> None:
        """`address` frames only `functions` (None: every one its drive has)."""
        if functions is None:
            self._known.pop(address, None)
        else:
            self._known[address] = frozenset(functions)

    def stall(self, address: int, until: float) -> None:
        """`address` answers nothing before `until` (monotonic); what it took meanwhile it
        answers after, in order."""
        self._stalled_until[address] = until

    def drop(self, address: int, rate: float) -> None:
        """`address` never answers this share of its requests, at random."""
        if not 0.0 <= rate <= 1.0:
            raise ValueError(f"drop rate {rate} is outside 0..1")
        self._drop_rate[address] = rate

    def refuse(self, address: int, code: int | None) -> None:
        """`address` answers every request with exception `code` (None: answers again)."""
        if code is None:
            self._refusing.pop(address, None)
        else:
            self._refusing[address] = code

    def refusal(self, address: int) -> int | None:
        """The exception code `address` answers every request with now; None: it answers."""
        return self._refusing.get(address)

    def silent(self, address: int, function: int) -> bool:
        """Does `address` leave this request unanswered (a function it doesn't frame, a drop)?"""
        known = self._known.get(address)
        if known is not None and function not in known:
            self.unframed += 1
            return True
        rate = self._drop_rate.get(address, 0.0)
        if rate and self._random.random() < rate:
            self.dropped += 1
            return True
        return False

    def answers_from(self, address: int) -> float:
        """The earliest moment `address` may start answering (0.0: any time)."""
        return self._stalled_until.get(address, 0.0)
