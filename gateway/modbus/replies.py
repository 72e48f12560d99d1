"""What a reply to each function code looks like: how long it is, and whether it fits the request.

The length rule is what lets the RTU master end a reply the moment its last byte arrives instead
of waiting for silence (USB adapters deliver bytes in bursts, so silence lies). Lengths are of the
whole RTU frame (address, PDU, CRC). A rule returns

- `NEED_MORE` while the first bytes don't tell yet (2 bytes; 3 for a byte count at offset 2);
- `UNKNOWN_LENGTH` when they can't tell at all: the reply ends on silence, the CRC decides;
- else a length n. When n > the bytes seen, n may be a step: replies with several length fields
  (18H's two-byte count; 2BH/0EH's objects, each with its own length) say how far the header
  goes before they can say more. A reader reads up to n and asks again; once it has n bytes,
  n is the reply's length. That is how the line reads, and for every other code n is final at
  once.

The fit rule catches what RTU can't: it has no transaction id, so a late reply to an earlier
request could pass for this one's. A read's byte count must match what was asked, a write's echo
must repeat it. Only requests of the standard shape are checked; others pass as they are.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Final

from gateway.modbus.request_checks import MEI_DEVICE_IDENTIFICATION, bits, words

NEED_MORE: Final = 0
"""`rtu_reply_length` needs more header bytes before it can tell."""
UNKNOWN_LENGTH: Final = -1
"""`rtu_reply_length` cannot know: the reply ends on silence."""
EXCEPTION_REPLY: Final = 5
"""Address, function code + 80H, exception code, CRC."""
MAX_RTU_FRAME: Final = 256

ReplyLength = Callable[[bytes | bytearray, int], int]
"""(the reply's first bytes, the request's RTU length) -> its RTU length, see above."""
ReplyFits = Callable[[bytes, bytes], bool]
"""(request PDU, normal reply PDU) -> does the reply answer that request?"""


# -- lengths --------------------------------------------------------------------------------------


def byte_count(header: bytes | bytearray, request_length: int) -> int:
    """01H-04H 0CH 11H 14H 15H 17H: the byte at offset 2 counts the data that follows."""
    return 5 + header[2] if len(header) >= 3 else NEED_MORE


def fixed(length: int) -> ReplyLength:
    """05H 06H 0FH 10H (8), 07H (5), 0BH (8), 16H (10)."""

    def rule(header: bytes | bytearray, request_length: int) -> int:
        return length

    return rule


def echo(header: bytes | bytearray, request_length: int) -> int:
    """08H: the reply echoes the request's length (sub-function 0000H: the request itself)."""
    return request_length


def two_byte_count(header: bytes | bytearray, request_length: int) -> int:
    """18H: a two-byte count at offset 2 of the FIFO count and values that follow it."""
    if len(header) < 4:
        return NEED_MORE if len(header) < 3 else 4
    return _at_most_a_frame(6 + int.from_bytes(header[2:4], "big"))


def device_identification(header: bytes | bytearray, request_length: int) -> int:
    """2BH/0EH: eight header bytes, then `number of objects` (offset 7) objects of id, length,
    value. Other MEI types under 2BH have no length this table knows."""
    if len(header) < 3:
        return NEED_MORE
    if header[2] != MEI_DEVICE_IDENTIFICATION:
        return UNKNOWN_LENGTH
    if len(header) < 8:
        return 8
    end = 8
    for _ in range(header[7]):
        if len(header) < end + 2:
            return end + 2  # the next object's id and length are needed to go on
        end += 2 + header[end + 1]
        if end + 2 > MAX_RTU_FRAME:
            break
    return _at_most_a_frame(end + 2)


def unknown(header: bytes | bytearray, request_length: int) -> int:
    return UNKNOWN_LENGTH


def _at_most_a_frame(length: int) -> int:
    # Lengths that no RTU frame can have are garbage on the line: let silence and the CRC end it.
    return length if length <= MAX_RTU_FRAME else UNKNOWN_LENGTH


# -- fits -----------------------------------------------------------------------------------------


def always(request: bytes, reply: bytes) -> bool:
    return True


def _quantity(request: bytes, offset: int = 3) -> int:
    return int.from_bytes(request[offset : offset + 2], "big")


def bits_counted(request: bytes, reply: bytes) -> bool:
    """01H 02H: the byte count carries the bits asked for."""
    if len(request) != 5:
        return True
    return len(reply) >= 2 and reply[1] == bits(_quantity(request))


def words_counted(request: bytes, reply: bytes) -> bool:
    """03H 04H: the byte count carries the registers asked for."""
    if len(request) != 5:
        return True
    return len(reply) >= 2 and reply[1] == words(_quantity(request))


def echoed(length: int) -> ReplyFits:
    """05H 06H (5 bytes), 16H (7): the reply repeats the request."""

    def rule(request: bytes, reply: bytes) -> bool:
        return len(request) != length or reply == request

    return rule


def start_and_quantity_echoed(request: bytes, reply: bytes) -> bool:
    """0FH 10H: the reply repeats the function, start address and quantity."""
    return len(request) < 6 or reply == request[:5]


def read_words_counted(request: bytes, reply: bytes) -> bool:
    """17H: the byte count carries the registers asked to be read."""
    if len(request) < 10:
        return True
    return len(reply) >= 2 and reply[1] == words(_quantity(request))
