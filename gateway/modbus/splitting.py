"""Splitting a long register read or write into parts a drive takes, and joining the replies.

INVT drives take at most 16 words per request while SCADA may ask for 125; the router sends the
parts in order and answers as one request would have been answered. Only well-formed requests
(see `request_checks`) longer than the limit are split, and never one that runs past FFFFH.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Final

LAST_ADDRESS: Final = 0xFFFF
_START_AND_QUANTITY: Final = struct.Struct(">HH")


@dataclass(frozen=True, slots=True)
class Split:
    parts: Callable[[bytes, int], list[bytes] | None]
    """(well-formed request PDU, most words per part) -> the parts, or None: no split needed."""
    join: Callable[[bytes, Sequence[bytes]], bytes]
    """(request PDU, the parts' normal reply PDUs in order) -> the reply one request gets."""


def _spans(pdu: bytes, max_words: int) -> list[tuple[int, int, int]] | None:
    """(offset, start, words) of each part, or None when one request will do."""
    start, count = _START_AND_QUANTITY.unpack_from(pdu, 1)
    if count <= max_words or start + count > LAST_ADDRESS + 1:
        return None
    return [
        (offset, start + offset, min(max_words, count - offset))
        for offset in range(0, count, max_words)
    ]


def _read_parts(pdu: bytes, max_words: int) -> list[bytes] | None:
    spans = _spans(pdu, max_words)
    if spans is None:
        return None
    return [struct.pack(">BHH", pdu[0], start, words) for _, start, words in spans]


def _join_reads(pdu: bytes, replies: Sequence[bytes]) -> bytes:
    data = b"".join(reply[2:] for reply in replies)
    return bytes((pdu[0], len(data))) + data


def _write_parts(pdu: bytes, max_words: int) -> list[bytes] | None:
    spans = _spans(pdu, max_words)
    if spans is None:
        return None
    values = pdu[6:]
    return [
        struct.pack(">BHHB", pdu[0], start, words, 2 * words)
        + values[2 * offset : 2 * (offset + words)]
        for offset, start, words in spans
    ]


def _join_writes(pdu: bytes, replies: Sequence[bytes]) -> bytes:
    return pdu[:5]  # function, start, count: what one write would have echoed


REGISTER_READ: Final = Split(_read_parts, _join_reads)
"""03H 04H."""
REGISTER_WRITE: Final = Split(_write_parts, _join_writes)
"""10H."""
