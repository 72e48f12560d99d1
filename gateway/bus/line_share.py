"""How the line's time was shared lately between writes, broadcasts, polls and the rest.

Writes go before reads (a stop command must not wait behind polls), but a client that keeps writes
queued would then hold the line for everyone: 400 pipelined writes froze every reader for
seconds, and each broadcast holds the line for its whole turnaround. So while reads wait, writes
may take at most `write_share` of the line's time and broadcasts at most `broadcast_share`; with
nothing else waiting, they take all of it.

Polls go after client reads, but not never: while reads wait, polls take at most `poll_share` of
the line's time (telemetry and dead-drive checks go on under a SCADA that reads without pause).
On a line kept full by closed-loop clients every second of poll time is a second those clients
wait: a reader's median read took 1/(1 - share) as long with the polls beside it (8 readers at
19200 baud: polls at 13 % of the line made it 1.15x). Small by default, so the polls fill the
line's idle time and take little of a full one.

Line time is counted per transaction (timeouts and a broadcast's turnaround included), in sums that
decay with a half-life of a couple of seconds: recent use decides, an old burst is forgotten.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

HALF_LIFE_S = 2.0


class LineUse(Enum):
    WRITE = "write"
    BROADCAST = "broadcast"
    POLL = "poll"
    OTHER = "other"


# Read per transaction, as module globals (see `gateway.bus.queue`: an enum member read costs
# ~950 instructions on Python 3.11, a global ~45).
_POLL, _OTHER, _BROADCAST = LineUse.POLL, LineUse.OTHER, LineUse.BROADCAST


@dataclass(frozen=True, slots=True)
class LineShares:
    write_share: float = 0.5
    """Most of the line's time writes (broadcasts included) take while reads wait."""
    broadcast_share: float = 0.1
    """Most of the line's time broadcasts take while anything else waits."""
    poll_share: float = 0.05
    """Most of the line's time polls take while client reads wait."""


REBASE_AFTER_S = 64 * HALF_LIFE_S
"""How far the meter's weights may grow (2^64) before its sums are brought back to scale."""


class ShareMeter:
    """The decayed sums of line time, by kind.

    Nothing decays per charge: a charge at `now` is added weighed by 2^((now - origin) / half
    life), the sums kept scaled by that growing weight. What the shares decide is a ratio of two
    sums (`_within`), which the scale doesn't change: the same decisions as sums decayed at
    every charge and every look, for one `exp2` per charge and none per look. The weights are
    brought back to 1 (`_rebase`) before they could grow out of a float's range."""

    def __init__(self, shares: LineShares) -> None:
        self.shares = shares
        self._writes = 0.0  # broadcasts included
        self._broadcasts = 0.0
        self._polls = 0.0
        self._total = 0.0
        self._origin = 0.0
        """Where the weights are 1 (a `time.monotonic()` value)."""

    def charge(self, use: LineUse, seconds: float, now: float) -> None:
        """`seconds` of line time went to a transaction of this kind."""
        elapsed = now - self._origin
        if elapsed > REBASE_AFTER_S:
            self._rebase(now)
            elapsed = 0.0
        weighed = seconds * math.exp2(elapsed / HALF_LIFE_S)
        self._total += weighed
        if use is _POLL:
            self._polls += weighed
        elif use is not _OTHER:
            self._writes += weighed
            if use is _BROADCAST:
                self._broadcasts += weighed

    def writes_may_go(self, now: float) -> bool:
        """May a write go before the reads waiting now?"""
        return self._within(self._writes, self.shares.write_share)

    def broadcasts_may_go(self, now: float) -> bool:
        """May a broadcast go before the other requests waiting now?"""
        return self._within(self._broadcasts, self.shares.broadcast_share) and (
            self.writes_may_go(now)
        )

    def polls_may_go(self, now: float) -> bool:
        """May a poll go before the client reads waiting now?"""
        return self._within(self._polls, self.shares.poll_share)

    def _within(self, used: float, share: float) -> bool:
        if self._total <= 0 or share >= 1.0:  # 1: no limit, writes always first
            return True
        return used / self._total < share

    def _rebase(self, now: float) -> None:
        """Decay the sums to `now` and weigh charges from there (a sum long unused goes to 0)."""
        factor = math.exp2(-(now - self._origin) / HALF_LIFE_S)
        self._writes *= factor
        self._broadcasts *= factor
        self._polls *= factor
        self._total *= factor
        self._origin = now
