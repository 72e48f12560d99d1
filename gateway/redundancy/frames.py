"""What a frame heard on the line is: a master's request, a drive's reply, or one that reads as
both (05H, 06H and 08H: the reply echoes the request).

A request and a reply of one function code differ in length: a 03H request is 8 bytes, its reply
5 plus a byte count. A frame is taken for a request only when its CRC is good at the request's
length and not at the reply's: a reply's first 8 bytes carry a good CRC once in 65,536 replies,
but its own CRC at its own length then says what it is. Frames are cut where the one before
ended, and a silence ends what is held; bytes that start no frame are skipped one at a time
(noise, a frame's tail heard after a port opened mid-frame).
"""

from __future__ import annotations

from enum import Enum
from typing import Final, NamedTuple

from gateway.modbus.crc import crc_ok
from gateway.modbus.functions import (
    EXCEPTION_BIT,
    NEED_MORE,
    UNKNOWN_LENGTH,
    check_request,
    rtu_reply_length,
)

MAX_FRAME: Final = 256
ECHO_FORM: Final = frozenset({0x05, 0x06, 0x08})
"""Function codes whose reply is a copy of the request."""
_FIXED_REQUESTS: Final = {0x01: 8, 0x02: 8, 0x03: 8, 0x04: 8, 0x05: 8, 0x06: 8, 0x08: 8, 0x16: 10}
_COUNTED_REQUESTS: Final = {0x0F: 9, 0x10: 9}
"""Requests whose length is this plus the byte count at offset 6."""


class Kind(Enum):
    REQUEST = "request"
    REPLY = "reply"
    ECHO_FORM = "echo-form"
    """05H, 06H, 08H: a request or its reply, the bytes can't say which."""


class Frame(NamedTuple):
    kind: Kind
    data: bytes


def request_length(buffer: bytes | bytearray) -> int | None:
    """The RTU length of the request that starts `buffer`, None if unknown (yet)."""
    if len(buffer) < 2:
        return None
    function = buffer[1]
    if function in _FIXED_REQUESTS:
        return _FIXED_REQUESTS[function]
    if function in _COUNTED_REQUESTS and len(buffer) >= 7:
        return _COUNTED_REQUESTS[function] + buffer[6]
    return None


def _reply_length(buffer: bytes | bytearray) -> int | None:
    length = rtu_reply_length(buffer[:3], 8)
    return None if length in (NEED_MORE, UNKNOWN_LENGTH) else length


class FrameCutter:
    """Bytes in as they come, whole frames out; `silence` when the line went quiet: what is
    held is decided then (a frame that may still grow into a longer one is held until it can't)."""

    def __init__(self) -> None:
        self._buffer = bytearray()

    def feed(self, data: bytes) -> list[Frame]:
        self._buffer += data
        return self._cut(final=False)

    def silence(self) -> list[Frame]:
        """The line went quiet: the frames held are what they are now; a new one starts next."""
        frames = self._cut(final=True)
        self._buffer.clear()
        return frames

    def _cut(self, *, final: bool) -> list[Frame]:
        buffer = self._buffer
        frames: list[Frame] = []
        while len(buffer) >= 4:
            found = _frame_at_start(buffer, final)
            if found is None:
                break  # more bytes to come
            if found.data:
                frames.append(found)
                del buffer[: len(found.data)]
            else:
                del buffer[:1]  # no frame starts here: skip a byte
        if len(buffer) > MAX_FRAME:
            buffer.clear()
        return frames


def _frame_at_start(buffer: bytearray, final: bool) -> Frame | None:
    """The frame at the buffer's start; an empty one if none can start there; None to wait for
    more bytes (never when `final`)."""
    function = buffer[1]
    if function & EXCEPTION_BIT:
        if len(buffer) < 5:
            return Frame(Kind.REPLY, b"") if final else None
        return _checked(buffer, 5, Kind.REPLY)
    asked = request_length(buffer)
    answered = _reply_length(buffer)
    as_request = asked is not None and len(buffer) >= asked and crc_ok(buffer[:asked])
    as_reply = answered is not None and len(buffer) >= answered and crc_ok(buffer[:answered])
    if as_request and asked is not None:
        data = bytes(buffer[:asked])
        if function in ECHO_FORM:
            return Frame(Kind.ECHO_FORM, data)
        if not as_reply:
            if answered is not None and len(buffer) < answered and not final:
                return None  # a reply's first bytes may carry a good CRC: its own will tell
            if check_request(data[1:-2]) is None:
                return Frame(Kind.REQUEST, data)
    if as_reply and answered is not None:
        return Frame(Kind.REPLY, bytes(buffer[:answered]))
    longest = max(asked or 0, answered or 0, 8)
    return None if len(buffer) < longest and not final else Frame(Kind.REPLY, b"")


def _checked(buffer: bytearray, length: int, kind: Kind) -> Frame:
    data = bytes(buffer[:length])
    return Frame(kind, data if crc_ok(data) else b"")
