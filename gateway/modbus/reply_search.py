"""Finding the reply to an RTU request in the bytes received so far. Pure: bytes in, a verdict out.

Real lines put bytes before a reply that are not part of it, and a master that insists the reply
starts at the first byte it receives fails every request on such a line:
- a transceiver that switches its driver on glitches one byte (often 00H or FFH) just before the
  reply;
- a 2-wire adapter without echo suppression hands the master its own request back first.

So the reply is searched for, never assumed: a candidate starts with the expected address and the
request's function code (or its exception form), and ends where its length rule says
(`rtu_reply_length`); only a candidate whose CRC is right is complete. Bytes before it are
garbage (or the echo), counted and discarded, never trusted. A complete, CRC-correct frame from
another address is still reported, so the bus refuses it as a foreign reply exactly as before.

The earliest plausible candidate is the one waited for: a later offset is only tried once that
candidate has failed its CRC, or when the caller's deadline has passed (`after=`), so a reply still
arriving is never cut short by a "frame" found inside its own data.
"""

from __future__ import annotations

from enum import Enum
from typing import NamedTuple

from gateway.modbus.crc import crc_ok
from gateway.modbus.functions import (
    EXCEPTION_BIT,
    NEED_MORE,
    UNKNOWN_LENGTH,
    lookup,
    rtu_reply_length,
)

MAX_FRAME = 256
"""An RTU frame is at most this long: no length rule needs to see more."""
MIN_REPLY = 5
"""The shortest RTU reply: an exception (address, function, code, CRC)."""


class Found(Enum):
    COMPLETE = "complete"
    """`received[start:end]` is a whole frame with a good CRC (ours, or a foreign one)."""
    PARTIAL = "partial"
    """A plausible reply starts at `start`; more bytes are needed (`end` = its expected end, or
    0 while its header doesn't tell yet)."""
    SILENCE_ENDS = "silence_ends"
    """A reply of a function code whose length no rule gives starts at `start`: it ends on
    silence."""
    CORRUPT = "corrupt"
    """The only candidate, `received[start:end]`, has its full length but a wrong CRC."""
    NOTHING = "nothing"
    """No reply has started: every byte after the echo is garbage so far."""


# Immutable, and built per transaction: a NamedTuple costs a fraction of a frozen dataclass,
# whose __init__ goes through object.__setattr__ for every field.
class ReplySearch(NamedTuple):
    found: Found
    start: int
    end: int
    echo: int = 0
    """Bytes at the front that are the request itself, echoed by the adapter."""

    @property
    def garbage(self) -> int:
        """Bytes skipped before the reply that are neither the reply nor the echo."""
        return self.start - self.echo


def echo_passes_for_reply(request: bytes) -> bool:
    """Would the request's own echo pass every check of a reply to it?

    True for 05H, 06H and 08H/0000, whose normal reply repeats the request: their echo and their
    reply can't be told apart by their bytes, only by knowing that the adapter echoes.
    """
    if len(request) < 4:
        return False
    length = rtu_reply_length(request, len(request))
    pdu = request[1:-2]
    return length == len(request) and lookup(request[1]).fits(pdu, pdu)


def _echo_coming(received: bytes | bytearray, request: bytes) -> bool:
    """Is all that came so far the first part of `request` itself (an adapter's echo)?"""
    return len(received) < len(request) and received == request[: len(received)]


def search_reply(
    received: bytes | bytearray,
    request: bytes,
    *,
    adapter_echoes: bool = False,
    after: int = -1,
) -> ReplySearch:
    """Where the reply to the RTU frame `request` is in `received`, as far as it has come.

    `adapter_echoes`: the adapter is known to echo (seen before), so a front that repeats the
    request is the echo even where it would pass for the reply (05H, 06H). `after`: ignore
    candidates starting at or before this offset (the caller gave up waiting for that one).
    """
    echo = 0
    if (
        len(received) >= len(request)
        and received[: len(request)] == request
        and (adapter_echoes or not echo_passes_for_reply(request))
    ):
        echo = len(request)
    address, function = request[0], request[1]
    corrupt: ReplySearch | None = None
    size = len(received)
    for start in range(max(echo, after + 1), size):
        # All that came from here on: some rules (2BH/0EH, 18H) read the reply field by field.
        header = received[start : start + MAX_FRAME]
        length = rtu_reply_length(header, len(request))
        ours = header[0] == address and (
            len(header) < 2 or header[1] in (function, function | EXCEPTION_BIT)
        )
        if ours:
            if length == UNKNOWN_LENGTH:
                if not start and _echo_coming(received, request):
                    return ReplySearch(Found.PARTIAL, 0, len(request), echo)
                return ReplySearch(Found.SILENCE_ENDS, start, size, echo)
            if length == NEED_MORE or size - start < length:
                end = 0 if length == NEED_MORE else start + length
                return ReplySearch(Found.PARTIAL, start, end, echo)
            if crc_ok(received[start : start + length]):
                return ReplySearch(Found.COMPLETE, start, start + length, echo)
            if not start and _echo_coming(received, request):
                # Our own request coming back, so far: its first bytes read as a reply's
                # header (03H from 00xxH: a byte count of 0) but fail its CRC. The rest of the
                # echo, then the reply, are still to come.
                return ReplySearch(Found.PARTIAL, 0, len(request), echo)
            if corrupt is None:
                corrupt = ReplySearch(Found.CORRUPT, start, start + length, echo)
            continue  # fails its CRC from here: the reply may start further on
        if MIN_REPLY <= length <= size - start and crc_ok(received[start : start + length]):
            # A well-formed frame that isn't ours: another drive's reply. Reported, so the bus
            # counts and refuses it as such, rather than skipped as if it were noise.
            return ReplySearch(Found.COMPLETE, start, start + length, echo)
    if corrupt is not None:
        return corrupt
    return ReplySearch(Found.NOTHING, size, 0, echo)
