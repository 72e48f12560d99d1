"""What a bus counts: per address (`DriveStats`) and for the line (`BusStats`), plain numbers the
bus writes and metrics, the console and the benchmark read; and a caller's request answered
(`RequestDone`), as the request observers are told of it."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from typing import NamedTuple


@dataclass(slots=True)
class DriveStats:
    """The line's counters for one address (0: broadcasts), for metrics to read at scrape time."""

    transactions: int = 0
    retries: int = 0
    timeouts: int = 0
    bad_replies: Counter[str] = field(default_factory=Counter)
    exceptions: Counter[int] = field(default_factory=Counter)
    failed: int = 0
    late_replies: int = 0
    """Replies that came after their request had timed out, set aside (`LateReplies`)."""
    resyncs: int = 0
    """Diagnostic echoes sent after a timeout before anything else went to this drive."""
    line_s: float = 0.0
    """Time the line was held for this address, timeouts included: a dead drive's cost shows."""


@dataclass(slots=True)
class BusStats:
    """Counters a dashboard or the benchmark reads; plain numbers, written by the bus only.

    What happened on the wire is counted once, for the address it happened with (`drives`); the
    bus's totals of those counters are their sums, worked out when read (a scrape), not kept.
    """

    drives: dict[int, DriveStats] = field(default_factory=dict)
    requests: int = 0
    broadcasts: int = 0
    coalesced: int = 0
    queue_full: int = 0
    offline_rejected: int = 0
    port_errors: int = 0
    reopens: int = 0
    busy_s: float = 0.0
    min_gap_s: float | None = None

    @property
    def transactions(self) -> int:
        return sum(drive.transactions for drive in self.drives.values())

    @property
    def retries(self) -> int:
        return sum(drive.retries for drive in self.drives.values())

    @property
    def timeouts(self) -> int:
        return sum(drive.timeouts for drive in self.drives.values())

    @property
    def bad_replies(self) -> Counter[str]:
        return sum((drive.bad_replies for drive in self.drives.values()), Counter())

    @property
    def exceptions(self) -> Counter[int]:
        return sum((drive.exceptions for drive in self.drives.values()), Counter())

    @property
    def failed(self) -> int:
        return sum(drive.failed for drive in self.drives.values())

    @property
    def late_replies(self) -> int:
        return sum(drive.late_replies for drive in self.drives.values())

    @property
    def resyncs(self) -> int:
        return sum(drive.resyncs for drive in self.drives.values())


# Immutable, and built per transaction: a NamedTuple costs a fraction of a frozen dataclass,
# whose __init__ goes through object.__setattr__ for every field.
class RequestDone(NamedTuple):
    """One caller's request, answered: what metrics count and time per source and function."""

    bus: str
    address: int
    function: int
    client: str
    duration_s: float
    """From `request()` to its answer: queue wait, retries and time on the wire."""
    code: int | None
    """None for a normal reply, else the exception code the caller got (the drive's, 0AH, 0BH)."""
