"""The bytes heard on one line, with when they came, and the reply found among them.

The port hands every byte it takes in to `Receiver.take`, stamped with its arrival: the line
knows when it last went quiet even between transactions (a late reply, noise), which is where
every inter-frame gap starts.

The reply is searched for among the bytes received, not assumed to start at the first one
(`gateway.modbus.reply_search`): a glitch byte from a transceiver switching on, or the request
echoed by an adapter without echo suppression, is skipped and counted, never trusted. The
receiver also watches what real hardware does to replies (the longest silence inside one, an
echo where `echo: false` says there is none) and says once in the log what to change.
"""

from __future__ import annotations

import itertools
import logging
import time
from collections.abc import Callable

from gateway.bus.exchange import Stray
from gateway.bus.hardware_hints import burst_hint, echo_hint
from gateway.bus.line_settings import LineSettings
from gateway.errors import BadReply, ReplyTimeout
from gateway.modbus.reply_search import MIN_REPLY, Found, ReplySearch, search_reply

log = logging.getLogger(__name__)

MAX_BUFFERED = 4096
"""Bytes kept while nobody reads (a frame is at most 256): a babbling line can't fill memory."""
_NOBODY = bytes(8)
"""A request no reply can answer (address 0): every whole, sound frame is found as another's."""
BURSTS_FROM_S = 0.005
"""A silence inside a reply longer than this (beyond its bytes' own wire time) means the adapter
delivers in bursts: worth a word in the log once. Clean USB adapters show well under 1 ms."""


def whole_frames(request: bytes, received: bytes | bytearray) -> list[bytes]:
    """The whole, sound frames among `received` (a reply to `request`, or anyone's), in order;
    what is between and after them is skipped."""
    frames = []
    while (search := search_reply(received, request)).found is Found.COMPLETE:
        frames.append(bytes(received[search.start : search.end]))
        received = received[search.end :]
    return frames


class Receiver:
    """One line's receive buffer: what came and when, the reply in it, what came before it."""

    def __init__(self, settings: LineSettings) -> None:
        self.settings = settings
        self.received = bytearray()
        self.quiet_since = 0.0
        """When the line last went quiet: the last byte heard (or a frame of ours sent)."""
        self.arrivals: list[tuple[int, float]] | None = None
        """While a reply is awaited: (buffer length after each read, its time)."""
        self.virtual = False
        """The port is a pty: no wire, so no wire timing to judge an echo by."""
        self.discarded_bytes = 0
        self.on_set_aside: Callable[[tuple[Stray, ...]], object] | None = None
        """Told of the whole, sound frames among bytes thrown away (`discard`): the bus
        accounts them in its ledger."""
        self.garbage_bytes = 0
        """Bytes skipped before replies: glitches, noise (`invt_gateway_line_garbage_bytes`)."""
        self.echoes = 0
        """Requests the adapter handed back although `echo: false` said it wouldn't."""
        self.longest_reply_silence_s = 0.0
        """The longest silence seen inside a reply (beyond its bytes' wire time): an adapter's
        burst delivery shows here."""
        self._bursts_told = False

    def opened(self, virtual: bool) -> None:
        """A port was opened on the line: nothing heard yet, and the line quiet from now."""
        self.received.clear()
        self.arrivals = None
        self.virtual = virtual
        self.quiet_since = time.monotonic()

    def take(self, data: bytes) -> None:
        """Bytes the port has just read: keep them, and when they came."""
        received = self.received
        received += data
        now = self.quiet_since = time.monotonic()
        arrivals = self.arrivals
        if len(received) > MAX_BUFFERED:
            excess = len(received) - MAX_BUFFERED
            self.discarded_bytes += excess
            del received[:excess]
            if arrivals is not None:
                arrivals.clear()  # offsets moved; the silence measure starts again
        if arrivals is not None:
            arrivals.append((len(received), now))

    def take_some(self, max_bytes: int) -> bytes:
        """Up to `max_bytes` from the front of the buffer (a drain's, an echo's reading)."""
        data = bytes(self.received[:max_bytes])
        del self.received[:max_bytes]
        return data

    def discard(self) -> None:
        """Throw away what nobody asked for (noise, a reply later than every drain); the whole,
        sound frames in it go to `on_set_aside`, for the bus's ledger (a late reply that came
        between transactions still tells what its drive no longer owes)."""
        received = self.received
        if received:
            self.discarded_bytes += len(received)
            told = self.on_set_aside
            frames = whole_frames(_NOBODY, received) if told is not None else ()
            received.clear()
            if frames and told is not None:
                heard_at = self.quiet_since
                told(tuple((frame, heard_at) for frame in frames))

    @property
    def echo_detected(self) -> bool:
        """The adapter has handed back a request though `echo: false` says it doesn't echo."""
        return self.echoes > 0

    def echo_deadline(self, frame: bytes, sent: float) -> float:
        """A copy of `frame` complete before this moment is the adapter's echo, not a reply.

        A reply can't be complete before the request has left the wire and the reply has
        crossed it: a copy of the request complete sooner is the adapter's echo (05H, 06H and
        08H replies are copies too; time tells them apart where the bytes can't). Not on a pty:
        a virtual line has no wire, and a peer behind it may answer at once.
        """
        if self.virtual:
            return 0.0
        return sent + self.settings.char_format.wire_time_s(len(frame))

    def search(self, frame: bytes, echo_by: float) -> ReplySearch:
        """Where the reply to `frame` stands among the bytes received so far."""
        echoes = self.echoes > 0 or self.arrived_by(len(frame), echo_by)
        return search_reply(self.received, frame, adapter_echoes=echoes)

    def arrived_by(self, count: int, moment: float) -> bool:
        """Had the first `count` bytes of this read arrived before `moment`?"""
        for end, at in self.arrivals or ():
            if end >= count:
                return at < moment
        return False

    def take_reply(self, search: ReplySearch, end: int) -> bytes:
        """Take `received[search.start:end]` as the reply: count what came before it."""
        if search.garbage:
            self.garbage_bytes += search.garbage
        if search.echo:
            self._echo_found()
        reply = bytes(self.received[search.start : end])
        self._note_silences(search.start, end)
        del self.received[:end]
        return reply

    def reply_at_deadline(self, frame: bytes, search: ReplySearch) -> bytes:
        """Nothing more came in time: the reply as far as it is, or why there is none."""
        received = self.received
        if search.found is Found.SILENCE_ENDS:
            return self.take_reply(search, len(received))
        if search.found is Found.PARTIAL:
            # The candidate never completed; a frame further on may have (the candidate was a
            # glitch that happened to look like the start of a reply).
            later = search_reply(
                received, frame, adapter_echoes=self.echo_detected, after=search.start
            )
            if later.found is Found.COMPLETE:
                return self.take_reply(later, later.end)
            partial = bytes(received[search.start :])
            raise BadReply("truncated", f"reply stopped after {len(partial)} bytes", partial)
        noise = bytes(received[search.echo :])
        if len(noise) >= MIN_REPLY:
            what = f"{len(noise)} bytes came, none of them a reply: {noise.hex(' ')}"
            raise BadReply("noise", what, noise)
        # A glitch byte or two is not an answer: the drive is silent as far as anyone can tell.
        raise ReplyTimeout(f"no reply to {frame[:2].hex(' ')} within the response timeout", noise)

    def _note_silences(self, start: int, end: int) -> None:
        """The longest silence inside the reply at `start:end`, from the arrival times."""
        arrivals = self.arrivals
        if not arrivals or len(arrivals) < 2 or (len(arrivals) == 2 and arrivals[0][0] <= start):
            return  # the reply came in one read after the mark: no silence inside it
        wire_time = self.settings.char_format.wire_time_s
        longest = 0.0
        for (before, before_at), (after, after_at) in itertools.pairwise(arrivals):
            if start < before < end:  # this read continued the reply after a pause
                silence = after_at - before_at - wire_time(min(after, end) - before)
                longest = max(longest, silence)
        if longest > self.longest_reply_silence_s:
            self.longest_reply_silence_s = longest
        if longest > BURSTS_FROM_S and not self._bursts_told:
            self._bursts_told = True
            log.warning("%s", burst_hint(self.settings.where, self.settings.port, longest))

    def _echo_found(self) -> None:
        self.echoes += 1
        if self.echoes == 1:
            log.warning("%s", echo_hint(self.settings.where))
