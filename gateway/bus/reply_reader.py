"""The rest of an attempt, read by the bus's own coroutine: the request's tail, its echo, the reply.

The line's reader callback finishes an attempt whose reply comes whole and valid while its caller
is held (`gateway.bus.line`); everything else is read here: a reply late, partial, corrupt or
ended by a silence, a broadcast's turnaround, an adapter's echo, the drain after a timeout or a
bad reply, and a marker's answer (`gateway.bus.late_replies`). The reply is found by
the line's `Receiver`; this waits for its bytes on the `Port`, each wait bounded by the timeouts
the line's module docstring sets out. Whole, sound frames that are not the answer are set aside
and returned with the outcome, for the bus's ledger (`gateway.bus.late_replies`) to account.
"""

from __future__ import annotations

import time

from gateway.bus.exchange import Exchange, Sending, Stray
from gateway.bus.late_replies import is_reply_to
from gateway.bus.line_settings import LineSettings
from gateway.bus.port import Port
from gateway.bus.receiver import Receiver, whole_frames
from gateway.bus.rts import RtsSwitch
from gateway.errors import BadReply, ReplyTimeout
from gateway.modbus.functions import DIAGNOSTICS
from gateway.modbus.reply_search import Found
from gateway.modbus.rtu import MAX_FRAME, check_reply

# Stray bytes that keep coming for this long are noise on the line, not a frame: stop draining and
# let the next request take its chances rather than block the bus forever.
MAX_DRAIN_S = 1.0


class ReplyReader:
    """One open port's attempts, finished by their caller."""

    def __init__(
        self, settings: LineSettings, receiver: Receiver, port: Port, rts: RtsSwitch | None
    ) -> None:
        self.settings = settings
        self.receiver = receiver
        self._port = port
        self._rts = rts

    async def finish(
        self,
        sending: Sending,
        *,
        expect_reply: bool,
        timeout_s: float,
        owed: tuple[bytes, ...] = (),
    ) -> Exchange:
        """The rest of an attempt begun by `SerialLine.send_after_gap`: the frame's tail, its
        echo, the reply.

        The reply is the first whole frame that answers the request and none of `owed` (the
        requests its drive may still answer: `gateway.bus.late_replies`). Every other whole,
        sound frame (another drive's, a late one) is set aside in the exchange's `strays` and
        the wait goes on to the response deadline: the asked drive's reply may still come.
        Raises ReplyTimeout (after a drain whose frames are set aside too) or BadReply for a
        corrupt, partial or noisy reply (after draining the line), with their `strays`.
        """
        frame, started = sending.frame, sending.started
        receiver = self.receiver
        sent = await self._complete_request(sending)
        if not expect_reply:
            receiver.quiet_since = max(receiver.quiet_since, sent + self.settings.turnaround_s)
            return Exchange(None, sending.gap_s, receiver.quiet_since - started)
        strays: list[Stray] = []
        try:
            while True:
                reply = await self._read_reply(frame, sent, sent + timeout_s)
                pdu = self._answer(frame, reply, owed, strays)
                if pdu is not None:
                    break
        except ReplyTimeout as exc:
            strays += self._frames(frame, await self._drain(self.settings.drain_s))
            raise ReplyTimeout(str(exc), exc.received, tuple(strays)) from None
        except BadReply as exc:
            strays += self._frames(frame, await self._drain(0.0))
            exc.strays = tuple(strays)
            raise
        finally:
            self._heard_by_now()
        heard_at = self._heard_at()
        return Exchange(pdu, sending.gap_s, receiver.quiet_since - started, heard_at, tuple(strays))

    def _answer(
        self,
        frame: bytes,
        reply: bytes,
        owed: tuple[bytes, ...],
        strays: list[Stray],
    ) -> bytes | None:
        """The PDU of `reply` if it answers `frame` and can't be an `owed` request's reply;
        else None, `reply` set aside (whole and sound). Raises BadReply for a corrupt one."""
        try:
            pdu = check_reply(frame, reply)
        except BadReply as exc:
            if exc.kind in ("crc", "truncated"):
                raise
            strays.append((reply, self.receiver.quiet_since))  # sound, but not the answer
            return None
        # An echo of another value (an older one's) passes `check_reply`: `is_reply_to` has
        # the echo's rule too.
        if (frame[1] == DIAGNOSTICS and not is_reply_to(frame, reply)) or any(
            is_reply_to(request, reply) for request in owed
        ):
            strays.append((reply, self.receiver.quiet_since))
            return None
        return pdu

    def _frames(self, frame: bytes, drained: bytearray) -> list[Stray]:
        """The whole, sound frames among what a drain heard, each stamped with its end."""
        return [(whole, self.receiver.quiet_since) for whole in whole_frames(frame, drained)]

    def _heard_by_now(self) -> None:
        """A port without arrival times (a URL's): the line's last sound is now, the safe bet."""
        if not self._port.watched:
            self.receiver.quiet_since = max(self.receiver.quiet_since, time.monotonic())

    def _heard_at(self) -> float:
        """When the reply's last byte arrived; 0.0 where the port gives no arrival times."""
        return self.receiver.quiet_since if self._port.watched else 0.0

    async def _complete_request(self, sending: Sending) -> float:
        """Put the rest of `sending`'s frame on the wire (and read back its echo, where the
        adapter is said to echo); when its last character has left the wire."""
        frame, started = sending.frame, sending.started
        wire_s = self.settings.char_format.wire_time_s(len(frame))
        if self._rts is not None:
            sent = await self._rts.finish(frame, sending.write_at, wire_s)
        else:
            if sending.written < len(frame):
                await self._port.write(frame[sending.written :])
            sent = started + wire_s
        # Our own frame holds the line until its last character has left; bytes heard since it
        # went out (the caller was held until the reply began) tell the line's last sound.
        receiver = self.receiver
        if not receiver.received:
            receiver.quiet_since = max(receiver.quiet_since, sent)
        if self.settings.echo:
            await self._read_echo(frame, sent)
        return sent

    async def _read_reply(self, frame: bytes, sent: float, response_deadline: float) -> bytes:
        """Find the reply to `frame` among the bytes that arrive, and return exactly it.

        Bytes before the reply that can't start it (a glitch, the adapter's echo) are skipped;
        bytes after it stay for `_discard_pending`. `check_reply` judges what is returned.
        """
        receiver = self.receiver
        if receiver.arrivals is None:  # else: kept since the caller was held
            receiver.arrivals = [(len(receiver.received), receiver.quiet_since)]
        try:
            echo_by = receiver.echo_deadline(frame, sent)
            return await self._search_reply(frame, response_deadline, echo_by)
        finally:
            receiver.arrivals = None

    async def _search_reply(self, frame: bytes, response_deadline: float, echo_by: float) -> bytes:
        receiver = self.receiver
        char_timeout = self.settings.char_timeout_s
        wire_time = self.settings.char_format.wire_time_s
        # However the bytes trickle in, one attempt ends: a babbling line can't hold the bus.
        give_up = response_deadline + wire_time(MAX_FRAME) + char_timeout
        while True:
            seen = len(receiver.received)
            if not seen and await self._more_bytes(0, min(response_deadline, give_up)):
                continue  # the usual start: nothing to search until the first bytes come
            search = receiver.search(frame, echo_by)
            found = search.found
            if found is Found.COMPLETE or found is Found.CORRUPT:
                return receiver.take_reply(search, search.end)
            if found is Found.SILENCE_ENDS:
                deadline = receiver.quiet_since + char_timeout
            elif found is Found.PARTIAL:
                missing = search.end - seen if search.end else 3
                # Not ended by a silence before the response deadline: bursts cut replies.
                deadline = max(
                    response_deadline, receiver.quiet_since + char_timeout + wire_time(missing)
                )
            else:
                deadline = response_deadline
            if await self._more_bytes(seen, min(deadline, give_up)):
                continue
            return receiver.reply_at_deadline(frame, search)

    async def _more_bytes(self, seen: int, deadline: float) -> bool:
        """Wait until more than `seen` bytes are buffered (True) or `deadline` passes (False)."""
        received = self.receiver.received
        while len(received) <= seen:
            if not await self._port.wait(deadline):
                return False
        return True

    async def _read_some(self, max_bytes: int, deadline: float) -> bytes:
        """Up to `max_bytes` that arrive before `deadline` (monotonic); b"" when none do."""
        self._port.check()
        if not self.receiver.received and not await self._port.wait(deadline):
            return b""
        return self.receiver.take_some(max_bytes)

    async def _read_echo(self, frame: bytes, sent: float) -> None:
        """Adapters without echo suppression hand back what we sent; it must match exactly."""
        echo = bytearray()
        deadline = sent + self.settings.char_timeout_s
        while len(echo) < len(frame):
            chunk = await self._read_some(len(frame) - len(echo), deadline)
            if not chunk:
                break
            echo += chunk
        if bytes(echo) != frame:
            await self._drain(0.0)
            raise BadReply("echo", f"echo {bytes(echo).hex(' ')} differs from what was sent")

    async def _drain(self, wait_for_late_s: float) -> bytearray:
        """Listen up to `wait_for_late_s` for a late frame, then until the line is quiet; what
        came (at most a frame's worth: enough to tell a late reply)."""
        char_timeout = self.settings.char_timeout_s
        started = time.monotonic()
        deadline = started + max(wait_for_late_s, char_timeout)
        drained = bytearray()
        while True:
            now = time.monotonic()
            if now >= deadline or now - started > MAX_DRAIN_S:
                return drained
            data = await self._read_some(256, deadline)
            if data:
                self.receiver.discarded_bytes += len(data)
                if len(drained) < MAX_FRAME:
                    drained += data
                # A late frame is arriving: follow it to its end, then stop.
                deadline = self.receiver.quiet_since + char_timeout
