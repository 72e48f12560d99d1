"""Which registers a request reads or writes, for the rules that allow or refuse registers.

Only requests that address registers have any (03H 04H 06H 10H 16H 17H); coils, diagnostics and
the rest have none. A request too short to say which registers it means is taken to touch all
of them: a rule that refuses registers catches it, one that allows some doesn't (the drive would
refuse it anyway). A count of 0 is invalid, but it names its start register: that one counts.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from typing import Final

Span = tuple[int, int]
"""First and last register, both included."""
RegistersTouched = Callable[[bytes], tuple[Span, ...] | None]
"""(request PDU) -> the spans it reads or writes, or None for a request without registers."""

LAST_REGISTER: Final = 0xFFFF
EVERY_REGISTER: Final[tuple[Span, ...]] = ((0, LAST_REGISTER),)
_TWO_WORDS: Final = struct.Struct(">HH")
_FOUR_WORDS: Final = struct.Struct(">HHHH")


def none(pdu: bytes) -> tuple[Span, ...] | None:
    return None


def block(pdu: bytes) -> tuple[Span, ...] | None:
    """03H 04H 10H: start address and count at offset 1."""
    if len(pdu) < 5:
        return EVERY_REGISTER
    start, count = _TWO_WORDS.unpack_from(pdu, 1)
    return (_block(start, count),)


def single(pdu: bytes) -> tuple[Span, ...] | None:
    """06H 16H: one register at offset 1."""
    if len(pdu) < 3:
        return EVERY_REGISTER
    address = int.from_bytes(pdu[1:3], "big")
    return ((address, address),)


def read_and_write(pdu: bytes) -> tuple[Span, ...] | None:
    """17H: the block it reads and the block it writes."""
    if len(pdu) < 9:
        return EVERY_REGISTER
    read_start, read_count, write_start, write_count = _FOUR_WORDS.unpack_from(pdu, 1)
    return (_block(read_start, read_count), _block(write_start, write_count))


def _block(start: int, count: int) -> Span:
    return start, min(start + max(count, 1) - 1, LAST_REGISTER)
