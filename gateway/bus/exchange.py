"""What one attempt on the line is and did: the frame on its way, the exchange it made."""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

Stray = tuple[bytes, float]
"""A whole, sound frame set aside during an attempt (not its answer), and when the line last
heard it (`gateway.bus.late_replies`)."""


@dataclass(slots=True, eq=False)
class Sending:
    """An attempt whose frame has started to go out.

    Slots, not a NamedTuple: its fields are read several times on a transaction's path, and
    Python 3.11 specialises a slot's read, not a NamedTuple field's (a descriptor call each)
    nor a NamedTuple's unpacking (a tuple subclass is iterated). Made once per transaction;
    with its reads it costs what the NamedTuple built in C did (`bench --instructions`, within
    its spread), read as plainly as any record. Not changed once made; compared by identity
    (`eq=False`: hashable, so a round's default, `gateway.bus.gap_keeper`)."""

    frame: bytes
    started: float
    """When the first byte was handed to the port (`time.monotonic()`)."""
    gap_s: float
    """Silence kept before it (measured, not assumed)."""
    written: int
    """Bytes the port took at once; `finish` writes the rest."""
    write_at: float = 0.0
    """RTS direction control with a set-up delay: when `finish` may write the frame (the
    driver was switched on at `started`)."""


# Immutable, made off a plain read's common path (the bus coroutine's attempts, the tap).
class Exchange(NamedTuple):
    """What one attempt did on the wire."""

    reply_pdu: bytes | None
    """The reply's PDU, or None for a broadcast."""
    gap_s: float
    """Silence kept before the request (measured, not assumed)."""
    busy_s: float
    """Time the line was busy with this exchange: request, drive's delay, reply."""
    reply_heard_at: float = 0.0
    """When the reply's last byte arrived (`time.monotonic()`); 0.0 when not known (a broadcast,
    a URL port without arrival times)."""
    strays: tuple[Stray, ...] = ()
    """Whole, sound frames that came before the reply and are not its answer, set aside with
    when each was heard (`gateway.bus.late_replies`)."""
