"""The drive side of RTU framing: where a request ends. Pure: bytes and times in, frames out.

A request ends at the length its function code implies (03H, 06H, 08H: 8 bytes; 10H: 9 + the
byte count at offset 6). When those bytes fail the CRC, or the code is unknown, the frame ends on a
silence of t3.5 instead, and the CRC over everything received decides: a good CRC is a frame of an
unexpected length (the drive answers 06H "data frame error"), a bad one is garbage, dropped. Either
way the receiver is back in step after the silence, as a real drive resynchronises.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

from gateway.modbus.crc import crc_ok

FIXED_REQUESTS: Final = {0x03: 8, 0x06: 8, 0x08: 8}
WRITE_MULTIPLE: Final = 0x10
MAX_FRAME: Final = 256
MIN_FRAME: Final = 4
"""Address, function code and CRC: anything shorter cannot be a frame."""


@dataclass(frozen=True)
class ReceivedFrame:
    data: bytes
    first_byte_at: float
    last_byte_at: float
    valid: bool
    """CRC good (and long enough to hold an address, a function code and the CRC)."""


def knows_length(function: int) -> bool:
    return function in FIXED_REQUESTS or function == WRITE_MULTIPLE


def request_length(buffer: bytes | bytearray) -> int | None:
    """Expected RTU length of the request starting `buffer`: None when it can't be known (yet)."""
    if len(buffer) < 2:
        return None
    function = buffer[1]
    if function in FIXED_REQUESTS:
        return FIXED_REQUESTS[function]
    if function == WRITE_MULTIPLE and len(buffer) >= 7:
        return 9 + buffer[6]
    return None


class RequestAssembler:
    """Collects bytes as they arrive and cuts them into frames."""

    def __init__(self, silence_s: float) -> None:
        self.silence_s = silence_s
        self._buffer = bytearray()
        self._first_at = 0.0
        self._last_at = 0.0
        self._await_silence = False

    def feed(self, data: bytes, at: float) -> list[ReceivedFrame]:
        """Add bytes that arrived at `at`; return the frames they complete."""
        if not self._buffer:
            self._first_at = at
        self._buffer += data
        self._last_at = at
        frames: list[ReceivedFrame] = []
        while self._buffer and not self._await_silence:
            if len(self._buffer) >= 2 and not knows_length(self._buffer[1]):
                self._await_silence = True  # a code the drive can't size ends on silence
                break
            expected = request_length(self._buffer)
            if expected is None:
                break  # the header isn't complete yet
            if len(self._buffer) < expected:
                break
            candidate = bytes(self._buffer[:expected])
            if not crc_ok(candidate):
                self._await_silence = True
                break
            frames.append(ReceivedFrame(candidate, self._first_at, at, valid=True))
            del self._buffer[:expected]
            self._first_at = at
        if len(self._buffer) > MAX_FRAME:
            self._await_silence = True
        return frames

    def silence_deadline(self) -> float | None:
        """When the bytes held so far end on silence, if no more arrive."""
        return self._last_at + self.silence_s if self._buffer else None

    def on_silence(self, now: float) -> list[ReceivedFrame]:
        """The frame (or garbage) that a silence up to `now` ends, if any."""
        deadline = self.silence_deadline()
        if deadline is None or now < deadline:
            return []
        data = bytes(self._buffer)
        self._buffer.clear()
        self._await_silence = False
        valid = MIN_FRAME <= len(data) <= MAX_FRAME and crc_ok(data)
        return [ReceivedFrame(data, self._first_at, self._last_at, valid)]
