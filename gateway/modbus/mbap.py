"""The Modbus-TCP application header (MBAP), pure bytes.

bytes 0-1  transaction id   echoed in the reply
bytes 2-3  protocol id      0 for Modbus
bytes 4-5  length           bytes that follow: unit id + PDU, so 2..254 (PDU at most 253)
byte  6    unit id          which drive, routed by the gateway
"""

from __future__ import annotations

import struct
from typing import NamedTuple

from gateway.errors import MalformedFrame

HEADER_LENGTH = 7
MIN_LENGTH = 2
MAX_LENGTH = 254
COUNTED_FROM = HEADER_LENGTH - 1
"""The length field counts the bytes from here (the unit id) to the frame's end."""
MIN_FRAME = COUNTED_FROM + MIN_LENGTH
MAX_FRAME = COUNTED_FROM + MAX_LENGTH
"""A whole frame's size in bytes is within these."""
_HEADER = struct.Struct(">HHHB")
read_header = _HEADER.unpack_from
"""(transaction id, protocol id, length, unit id) from the front of a buffer, unchecked: a C
call, no Python frame, for a caller that checks the fields itself (the Modbus-TCP server's fast
path, once per request); `frame_header` checks them."""


# Immutable, and built per transaction: a NamedTuple costs a fraction of a frozen dataclass,
# whose __init__ goes through object.__setattr__ for every field.
class MbapHeader(NamedTuple):
    transaction_id: int
    protocol_id: int
    length: int
    unit_id: int

    @property
    def pdu_length(self) -> int:
        return self.length - 1


def parse_header(data: bytes) -> MbapHeader:
    """Parse the 7 header bytes; raise MalformedFrame for anything a Modbus client can't mean."""
    if len(data) != HEADER_LENGTH:
        raise MalformedFrame(f"MBAP header needs {HEADER_LENGTH} bytes, got {len(data)}")
    header = MbapHeader(*_HEADER.unpack(data))
    if header.protocol_id != 0:
        raise MalformedFrame(f"protocol id {header.protocol_id}, expected 0")
    if not MIN_LENGTH <= header.length <= MAX_LENGTH:
        raise MalformedFrame(f"length {header.length} outside {MIN_LENGTH}..{MAX_LENGTH}")
    return header


def frame_header(buffer: bytes | bytearray) -> tuple[int, int, int]:
    """`parse_header` for a server reading a stream: the header at the front of `buffer` (at
    least `HEADER_LENGTH` bytes) as (transaction id, unit id, PDU length), read in place.
    Once per request: no header object, no copy of the bytes; the same checks, the same errors.
    """
    transaction_id, protocol_id, length, unit_id = _HEADER.unpack_from(buffer)
    if protocol_id or not MIN_LENGTH <= length <= MAX_LENGTH:
        parse_header(bytes(buffer[:HEADER_LENGTH]))  # raises, saying which field and why
    return transaction_id, unit_id, length - 1


def build_adu(transaction_id: int, unit_id: int, pdu: bytes) -> bytes:
    """MBAP header + PDU."""
    return _HEADER.pack(transaction_id, 0, len(pdu) + 1, unit_id) + pdu
