"""RTU frames: address, PDU, CRC (low byte first). Pure functions, no I/O."""

from __future__ import annotations

import struct
from dataclasses import dataclass
from functools import lru_cache

from gateway.errors import BadReply
from gateway.modbus.crc import crc16, crc16_from, crc16_words, crc_bytes, words_of
from gateway.modbus.functions import EXCEPTION_BIT, lookup

BROADCAST_ADDRESS = 0
MAX_FRAME = 256


def build_frame(address: int, pdu: bytes) -> bytes:
    """address + PDU + CRC."""
    body = bytes((address,)) + pdu
    return body + crc_bytes(body)


@lru_cache(maxsize=1024)
def request_frame(address: int, pdu: bytes) -> bytes:
    """`build_frame` for requests, remembered: a SCADA client and the poller ask the same
    questions over and over, and a hit (a hash of bytes, in C) costs a small part of working
    the CRC out in Python again. Bounded: a client sending ever new requests evicts the oldest."""
    return build_frame(address, pdu)


@dataclass(frozen=True, slots=True)
class PlainRead:
    """What the normal reply to one plain read request (03H or 04H, 8 bytes) is known by
    before it comes (`plain_read`). Slots, not a NamedTuple: its fields are read once per
    transaction, and Python 3.11 specialises a slot's read, not a NamedTuple field's (a
    descriptor call each); it is made once per request frame (`plain_read` remembers it)."""

    request: bytes
    length: int
    """The reply's length: address, function, byte count, the words, CRC."""
    head: bytes
    """Its address, function and byte count."""
    register: int
    """The CRC register after `head` (`crc16_from`)."""
    like_request: bool
    """`head` is how the request itself begins too: an adapter's echo could pass for it."""
    rest: struct.Struct
    """Takes the words after `head` (the reply's words and its CRC) out of it."""


@lru_cache(maxsize=1024)
def plain_read(request: bytes) -> PlainRead | None:
    """`PlainRead` of the RTU `request` when it is a plain read; None for any other request,
    whose reply only the reply search (`gateway.modbus.reply_search`) may size. Remembered, as
    `request_frame` is: the same frames come back, and a hit is a hash lookup in C."""
    if len(request) != 8 or request[1] not in (3, 4):
        return None
    count = (request[4] << 8) | request[5]
    if not 0 < count <= 125:
        return None
    length = 5 + 2 * count
    head = bytes((request[0], request[1], length - 5))
    register = crc16_from(0xFFFF, head, 0)
    return PlainRead(
        request, length, head, register, request[2] == length - 5, words_of((length - 3) // 2)
    )


def plain_read_reply(received: bytes | bytearray, expected: PlainRead) -> bytes | None:
    """The PDU of the normal reply to the plain read `expected.request` when `received` is
    exactly that reply and its CRC is right; else None, and the reply search decides.

    What the search would find at offset 0 for such bytes, checked directly: the search also
    takes the first candidate with the expected address, function and byte count whose CRC is
    right, and `check_reply` then asks no more of a read's reply than its byte count. Bytes
    that begin with the request itself are left to the search (an adapter's echo). Once per
    read on a busy line: the three bytes known before the reply comes are compared at once, and
    the CRC worked out from the register after them; what is known of the request is the
    caller's (`plain_read`, looked up once per request sent).
    """
    request = expected.request
    if (
        len(received) == expected.length
        and received.startswith(expected.head)
        and (not expected.like_request or received[: len(request)] != request)
        and crc16_words(expected.register, expected.rest.unpack_from(received, 3)) == 0
    ):
        return bytes(received[1:-2])
    return None


def check_reply(request: bytes, reply: bytes, *, crc_checked: bool = False) -> bytes:
    """Validate `reply` as the answer to the RTU `request`; return its PDU.

    Raises BadReply with kind `crc`, `truncated`, `address` or `function`, in that order: a frame
    whose CRC is wrong says nothing reliable about its address. `crc_checked`: the reply search
    has just checked this very frame's CRC (`Found.COMPLETE`), so it is not computed again.
    """
    if len(reply) < 4:
        raise BadReply("truncated", f"reply of {len(reply)} bytes is too short", reply)
    if not crc_checked and crc16(reply) != 0:  # a frame and its own CRC: 0 (`crc_ok`)
        raise BadReply("crc", f"bad CRC in reply {reply.hex(' ')}", reply)
    if reply[0] != request[0]:
        raise BadReply(
            "address", f"reply from address {reply[0]} to a request for {request[0]}", reply
        )
    function = request[1]
    if reply[1] not in (function, function | EXCEPTION_BIT):
        raise BadReply(
            "function", f"reply function {reply[1]:#04x} to a request {function:#04x}", reply
        )
    pdu = reply[1:-2]
    if not pdu[0] & EXCEPTION_BIT and not lookup(function).fits(request[1:-2], pdu):
        # RTU has no transaction id: a reply that doesn't fit what was asked is most likely a
        # late answer to an earlier request, and must not pass for this one's.
        raise BadReply("mismatch", f"reply {pdu.hex(' ')} does not answer the request", reply)
    return pdu


def split_frame(frame: bytes) -> tuple[int, bytes]:
    """(address, PDU) of a frame whose CRC is already known to be good."""
    return frame[0], frame[1:-2]
