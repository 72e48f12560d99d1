"""What one attempt on the line is and did: the frame on its way, the exchange it made."""

from __future__ import annotations

from typing import NamedTuple

Stray = tuple[bytes, float]
"""A whole, sound frame set aside during an attempt (not its answer), and when the line last
heard it (`gateway.bus.late_replies`)."""


# Immutable, and built per transaction: a NamedTuple costs a fraction of a frozen dataclass,
# whose __init__ goes through object.__setattr__ for every field.
class Sending(NamedTuple):
    """An attempt whose frame has started to go out.

    A NamedTuple: made once per transaction, in C (`tuple.__new__`, `gateway.bus.gap_keeper`).
    Where a transaction's own path reads several of its fields, it unpacks them in one
    instruction: Python 3.11 specialises a tuple's unpacking, not a NamedTuple field's read
    (a descriptor call each, some 200 instructions, callgrind)."""

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


# A NamedTuple for the reason given at `Sending`.
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
