"""The inter-frame gap before every frame on one line, and the caller held through back-to-back
transactions (`GapKeeper`), apart from the port, the receiver and the reading that the line
(`gateway.bus.line`) puts together.

The gap is kept with an exact timer (`gateway.bus.line_timer`), not with asyncio's millisecond
timeouts, from the line's last sound (`Receiver.quiet_since`); its wake-up comes a learnt lead
early (`gateway.bus.gap_lead`) and the rest is waited out on the clock, so a frame leaves as its
gap ends, never before. While requests keep coming, the port's reader callback (`heard`) finishes
each attempt whose reply is whole and valid, keeps the gap and sends the next frame, the caller
held all along: a busy line costs the loop one wake-up when a reply arrives and one when the gap
ends, and no pass for the caller's coroutine.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial

from gateway.bus.exchange import Sending
from gateway.bus.gap_lead import GapLead, loop_spin_budget
from gateway.bus.line_settings import LineSettings
from gateway.bus.line_timer import LineTimer
from gateway.bus.line_user import LineUser
from gateway.bus.port import Port
from gateway.bus.receiver import Receiver
from gateway.bus.rts import RtsSwitch
from gateway.bus.wakeup import MovingDeadline, settle
from gateway.errors import BadReply, PortError
from gateway.modbus.reply_search import Found
from gateway.modbus.rtu import PlainRead, check_reply, plain_read, plain_read_reply

_NOT_SENT = Sending(b"", 0.0, 0.0, 0)
"""`_Round.sending` before the round's first hold (typed so, the reader callback reads it
without a check)."""

_NO_DEADLINE = math.inf
"""`MovingDeadline.deadline` when none is set (a module global: `math.inf` is an attribute
read more)."""

_STILL_COMING = b""
"""`_held_reply`: the held caller's reply is not all there yet (no PDU is empty)."""


@dataclass(slots=True)
class _Round:
    """One `send_after_gap` call: whom it sends for, and what came of it for its caller."""

    user: LineUser
    outcome: list[Sending | Exception | None]
    """Empty until a frame went out (its Sending), nothing was picked (None) or that failed."""
    may_idle: bool = True
    """When the user's `pick` has nothing at a gap's end, the caller may stay held, idle, for
    a request to come (`LineUser.idle_for`, `GapKeeper.kick`); False once an idle wait is over:
    the caller gets None then."""
    picked: bytes | None = None
    """A frame chosen before the gap's end that could not go out then (bytes came in the last
    microseconds of the gap, which starts again): it goes at the next gap's end, as a frame
    already on its way would, its transaction out of the queue meanwhile (a write queued then
    waits behind it; closing the bus answers it as the transaction being carried)."""

    at_gap_end: Callable[[], bool] | None = None
    """`GapKeeper._send_at_gap_end` for this round, made once: the timer is given it for every
    gap of the round (a transaction each on a busy line), not a new partial each time."""

    # While the round's caller is held until its reply (`GapKeeper._held` is the round): the
    # attempt the reply is for. Fields of the round, set per transaction, rather than a record
    # made for each hold (a NamedTuple built in C costs ~1,400 instructions, callgrind).
    sending: Sending = _NOT_SENT
    sent: float = 0.0
    """When the frame's last bit was on the wire: a copy of the request complete before
    `Receiver.echo_deadline(frame, sent)` is the adapter's echo (worked out only when a reply
    isn't taken at once: the common case needs no echo deadline)."""
    plain_read: PlainRead | None = None
    """What the normal reply is known by when the request is a plain read, else None
    (`gateway.modbus.rtu.plain_read`)."""

    def take_pick(self) -> bytes | None:
        """The frame to send now: the one chosen earlier, if any, else the user's pick."""
        picked, self.picked = self.picked, None
        return picked if picked is not None else self.user.pick()


class GapKeeper:
    """One line's inter-frame gap, and `send_after_gap`'s caller held until a reply needs it."""

    def __init__(
        self,
        settings: LineSettings,
        receiver: Receiver,
        discard_pending: Callable[[], None],
    ) -> None:
        self.settings = settings
        self.receiver = receiver
        self._discard_pending = discard_pending
        """The line's: throw away bytes nobody asked for; raises PortError if it is closed."""
        self._port: Port | None = None
        self._timer: LineTimer | None = None
        self._rts: RtsSwitch | None = None
        """RTS switched around each frame (`gateway.bus.rts`), where it is: the frame's writing
        and its reply's reading are then the caller's."""
        self._holding = False
        """`send_after_gap`'s caller is held until the reply's first bytes, or the response
        timeout (`_response_deadline`)."""
        self._response_deadline: MovingDeadline | None = None
        """The held caller's response timeout: it wakes the caller, whose own reading then
        finds the reply missing or incomplete."""
        self._held: _Round | None = None
        """The round of the caller held until its reply (its `sending`, `sent` and
        `plain_read`: what it sent), for the reader callback to finish the attempt
        itself."""
        self._idle: _Round | None = None
        """The round of a caller held while the line is idle: `kick` sends its next frame."""
        self.gap_lead = GapLead(settings.gap_s)
        """How long before the gap's end the timer wakes the line (`gateway.bus.gap_lead`)."""
        self._learns_lead = False
        self._char_time_s = settings.char_format.char_time_s
        """One character's wire time (`CharacterFormat.wire_time_s`, read once)."""
        self._readable_now: Callable[[int], list[tuple[int, int]]] | None = None
        """The watched port's `readable_now` (None for a URL port, or closed): bytes the kernel
        holds that the loop hasn't taken in yet (`Port.bytes_waiting`), one C call."""
        """The timer's wake-ups are exact (timerfd): the lead is learnt from them. Without a
        timerfd the loop's timer never fires early, and the lead stays 0."""

    def opened(self, port: Port, timer: LineTimer, rts: RtsSwitch | None) -> None:
        """The line's port is open, with its timer (and RTS switch): gaps are kept on them."""
        self._port, self._timer, self._rts = port, timer, rts
        self._readable_now = port.readable_now
        self._response_deadline = MovingDeadline(port.loop, port.wake)
        self._learns_lead = timer.exact
        self.gap_lead.budget = loop_spin_budget(port.loop)

    def closed(self) -> None:
        """The line's port is closed (its timer too): nobody is held any more."""
        self._held = None
        self._idle = None
        self._timer = None
        self._readable_now = None
        if self._response_deadline is not None:
            self._response_deadline.close()
            self._response_deadline = None

    async def send_after_gap(self, user: LineUser) -> Sending | None:
        """At the gap's end, ask `user` for a frame and start writing it; None: nothing picked.

        The pick is made in the gap timer's wake-up, a learnt lead before the gap's end
        (`gateway.bus.gap_lead`), and the rest of the gap is waited out on the clock: the frame
        goes as the gap ends, with no pass of the loop between. Bytes heard during the gap
        start it again; a frame already chosen then goes at the new gap's end.

        With the frame's `LineUser.reply_timeout_s` set, the caller is held until the reply's
        first bytes (or that time). A reply whole and valid as it comes in is finished by the
        port's reader callback (`heard`), told to `LineUser.replied`, and the next frame picked
        and sent after the gap, the caller held all along: a busy line costs no pass of its
        coroutine. The caller gets the attempt its own reading must finish (a reply late,
        partial or bad: `finish`). With nothing picked, it stays held with the line idle for
        `LineUser.idle_for` (None: not at all), and `kick` sends a request queued meanwhile.
        """
        gap = self.settings.gap_s
        this = _Round(user, [])
        this.at_gap_end = at_gap_end = partial(self._send_at_gap_end, this)
        while True:
            self._discard_pending()
            due = self.receiver.quiet_since + gap
            now = time.monotonic()
            assert self._timer is not None  # _discard_pending raised if the port is closed
            if due <= now:
                frame = this.take_pick()
                if frame is not None:
                    return self._send_frame(frame, 0.0)
                idle_s = user.idle_for()
                if idle_s is None:
                    return None
                self._idle = this
                wake_at, action = now + idle_s, partial(self._idle_over, this)
            else:
                # Early by the learnt lead (0 where the timer has no timerfd: nothing learnt).
                wake_at = due - self.gap_lead.lead_s
                if wake_at <= now:  # within the lead already: wait out the rest, then look again
                    self.gap_lead.wait_out(due)
                    continue
                action = at_gap_end
            try:
                await self._timer.sleep_until(wake_at, action)
            finally:
                self._idle = None
                self._stop_holding()
            if this.outcome:
                outcome = this.outcome[0]
                if isinstance(outcome, Exception):
                    raise outcome  # in the caller's coroutine, not lost in a loop callback
                return outcome

    def _send_at_gap_end(self, this: _Round, timed: bool = True) -> bool:
        """The gap timer's action: send as the gap ends, if the line is still quiet and usable.
        True: the caller stays held (`LineTimer.sleep_until`) while the reply comes (`_hold`).

        `timed`: called by the timer's wake-up (or `fire_due`), a lead before the gap's end
        (`gateway.bus.gap_lead`): the next frame is chosen now and the rest of the gap is
        waited out on the clock, and how early or late that was teaches the lead.
        """
        port, receiver = self._port, self.receiver
        readable_now = self._readable_now
        if readable_now is None or port is None or not port.usable or receiver.received:
            # Closed, failed, not quiet after all, or a URL port (only its `discard_pending`
            # can tell if bytes came): `send_after_gap` looks again.
            return False
        if readable_now(0):
            receiver.quiet_since = time.monotonic()
            return False
        gap_end = receiver.quiet_since + self.settings.gap_s
        now = time.monotonic()
        lead = self.gap_lead
        if gap_end - lead.lead_s > now:
            return False  # woken before the lead (the timer's rounding slack): look again
        early = gap_end > now  # the line was seen quiet before the gap ended: look once more
        try:
            frame = this.take_pick()
        except Exception as exc:
            this.outcome.append(exc)
            return False
        if frame is None:
            if self._go_idle(this):
                return True
            this.outcome.append(None)
            return False
        ready_at = 0.0  # unknown
        if timed and self._learns_lead:
            ready_at = lead.ready(gap_end)
        elif early:
            lead.wait_out(gap_end)
        if early:
            ready_at = 0.0  # the port is asked once more (a system call) before the frame goes
            if readable_now(0):
                # Bytes came while the frame was chosen and the gap waited out: the line was
                # not quiet, so the gap starts again, and the frame goes at its end.
                receiver.quiet_since = time.monotonic()
                this.picked = frame
                return False
        try:
            # The frame's start: the clock `ready` read after the gap's end, a few statements
            # ago, if nothing came between; else read as it goes.
            sending = self._send_frame(frame, ready_at)
        except Exception as exc:
            this.outcome.append(exc)
            return False
        this.outcome.append(sending)
        return self._hold(this, sending)

    def _send_frame(self, frame: bytes, started: float) -> Sending:
        """Start writing `frame` now, through RTS where it switches; `started`: the clock's
        reading just taken (0.0: read here). What the port took at once is the attempt's
        `written`; `finish` writes the rest."""
        if not started:
            started = time.monotonic()
        gap_s = started - self.receiver.quiet_since
        rts = self._rts
        if rts is not None:
            write_at = rts.start(frame)
            return Sending(frame, started, gap_s, 0 if write_at else len(frame), write_at)
        port = self._port
        if port is None:
            raise PortError(f"{self.settings.port} is not open")
        return Sending(frame, started, gap_s, port.write_now(frame))

    def _hold(self, this: _Round, sending: Sending) -> bool:
        """`sending` is on its way: hold the round's caller until its reply (True), the reader
        callback finishing the attempt (`heard`) or waking the caller, whose own reading then
        decides; False: the caller's own reading does it all (`finish` has more to do than wait
        for the reply: the frame's tail to write, RTS to switch back, an echo to read first)."""
        within_s = this.user.reply_timeout_s
        frame = sending.frame
        if (
            within_s is None
            or self.settings.echo
            or self._rts is not None
            or sending.written != len(frame)
        ):
            return False
        port, timer = self._port, self._timer
        waiting = timer.waiting if timer is not None else None
        if waiting is None or port is None or port.waiter is not None:
            return False
        # The reader callback wakes whoever waits on the port (the held caller) when its reply
        # needs the caller's own reading; the response timeout does too, so a silent drive
        # still times out on time.
        port.waiter = waiting
        sent = sending.started + self._char_time_s * len(frame)  # the frame's last bit on the wire
        self._holding = True
        # Not on the gap timer: a timerfd write per transaction for a deadline that is almost
        # never reached costs more than the float stores of a moving deadline: its `deadline`
        # set directly while its timer comes no later (`MovingDeadline`), `set` otherwise.
        response = self._response_deadline
        assert response is not None
        response_at = response.deadline = sent + within_s
        if response_at < response.handle_at:
            response.set(response_at)
        # What came, when: for echoes and bursts (nothing has come since `received` was seen
        # empty at the gap's end: no other callback ran in between).
        self.receiver.arrivals = [(0, sent)]
        if frame is not this.sending.frame:
            # Else the round's last request again (a poller's, its frame remembered by the
            # bus): its reply's length is known, without the cache's lookup.
            this.plain_read = plain_read(frame)
        this.sending, this.sent = sending, sent
        self._held = this
        return True

    def kick(self) -> None:
        """A request was queued: a caller held with the line idle has its frame sent now, in
        this very callback, once the gap is over (at its end if bytes came meanwhile)."""
        this, timer = self._idle, self._timer
        if this is None or timer is None:
            return
        self._idle = None
        due = self.receiver.quiet_since + self.settings.gap_s
        wake_at = due - self.gap_lead.lead_s
        if wake_at > time.monotonic():  # the line was heard while idle: its gap first
            assert this.at_gap_end is not None  # set as the round began
            if timer.rearm(wake_at, this.at_gap_end):
                return
        elif timer.take_over() and self._send_at_gap_end(this, timed=False):
            return
        self._release_caller()  # the caller's loop takes it from here (`outcome` says what)

    def queued(self) -> None:
        """A request was queued: `kick`, then act on any gap of this loop's lines that has
        ended (`LineTimer.fire_due`), in one call (once per request). `kick` only when the
        caller is held idle: else it has nothing to do."""
        if self._idle is not None:
            self.kick()
        timer = self._timer
        if timer is not None:
            timer.fire_due()

    def _go_idle(self, this: _Round) -> bool:
        """`pick` had nothing at a gap's end: hold the caller, idle, for `kick` (True), if
        its round allows and the wait can be taken over."""
        if not this.may_idle or self._timer is None:
            return False
        idle_s = this.user.idle_for()
        if idle_s is None:
            return False
        if not self._timer.rearm(time.monotonic() + idle_s, partial(self._idle_over, this)):
            return False
        self._idle = this
        return True

    def _idle_over(self, this: _Round) -> bool:
        """The idle wait is over with nothing queued: the caller gets None (a last look first,
        for a request queued without a `kick`)."""
        self._idle = None
        this.may_idle = False
        if self._send_at_gap_end(this, timed=False):
            return True
        if not this.outcome:
            # Not sent (a URL port, whose bytes only its own reading sees; noise heard): the
            # caller still gets None, so the bus looks at its probes and its port now.
            this.outcome.append(None)
        return False

    def _stop_holding(self) -> None:
        self._held = None
        if not self._holding:
            return
        self._holding = False
        # `arrivals` stays: the caller's own reading goes on with the record the hold began (an
        # echo seen then is known for one by its time; a reply's silences are all measured).
        self._clear_response_deadline()
        port = self._port
        if port is not None and port.waiter is not None and port.waiter.done():
            port.waiter = None

    def heard(self, data: bytes) -> None:
        """The port's reader callback has read `data`: a held caller's reply, or news for
        whoever waits (the bytes are kept in the receiver, `Receiver.take`, unless they are the
        held caller's reply, taken at once).

        A reply whole and valid is the attempt's end, here: the hold ends, `replied` is told,
        the gap is kept after it and the next frame sent at its end, the caller held all along
        (what `send_after_gap`'s loop would do next)."""
        receiver = self.receiver
        held = self._held
        pdu: bytes | None = None
        if held is not None:
            expected = held.plain_read
            arrivals = receiver.arrivals
            if (
                expected is not None
                and expected.length == len(data)
                and not receiver.received
                and arrivals is not None
                and len(arrivals) == 1
            ):
                # The common case, checked directly: a read's reply, alone and in one piece (no
                # glitch before it, no pause inside it to measure), in this one read, as the
                # search would find it: taken at once, never kept in the buffer.
                pdu = plain_read_reply(data, expected)
            if pdu is not None:
                receiver.quiet_since = time.monotonic()  # as `Receiver.take` stamps it
            else:
                receiver.take(data)
                pdu = _held_reply(receiver, held)
        else:
            receiver.take(data)
        if pdu:
            assert held is not None  # a reply is only looked for while a caller is held
            # The hold is over: its caller stays held, now only by the gap timer.
            self._held = None
            receiver.arrivals = None
            self._holding = False
            deadline = self._response_deadline
            if deadline is not None:
                deadline.deadline = _NO_DEADLINE  # cleared (`MovingDeadline`: its timer stays)
            port = self._port
            assert port is not None
            port.waiter = None
            this = held
            this.outcome.clear()
            try:
                this.user.replied(held.sending, pdu, receiver.quiet_since)
                # What came after the reply: nobody asked for it. Not `_discard_pending`: the
                # port was read this very callback, and bytes that come during the gap are seen
                # at its end (`_send_at_gap_end`), which starts it again.
                if receiver.received:
                    receiver.discard()
                timer, port = self._timer, self._port
                kept = False  # else the caller's loop takes it from here (`outcome` says what)
                # A port gone or failed: the caller's own loop finds out what became of it.
                if port is not None and port.usable and timer is not None:
                    gap_end = receiver.quiet_since + self.settings.gap_s
                    wake_at = gap_end - self.gap_lead.lead_s
                    if wake_at > time.monotonic():
                        assert this.at_gap_end is not None  # set as the round began
                        kept = timer.rearm(wake_at, this.at_gap_end)
                    else:
                        kept = self._send_at_gap_end(this, timed=False)
                if not kept:
                    self._release_caller()
            except Exception as exc:  # in the caller's coroutine, not lost in the reader callback
                this.outcome[:] = [exc]
                self._release_caller()
        elif pdu is None:
            self._held = None  # the caller's own reading takes it from here
            assert self._port is not None
            self._port.wake()
        timer = self._timer
        if timer is not None:
            # Another line's gap that ended while this pass ran: acted on now. With no other
            # line's timer armed (one line on this loop, or the others idle) there is none, and
            # this line's own wake-up was just set for the gap to come (or its frame sent).
            armed = timer.loop_armed
            if armed and (len(armed) > 1 or timer not in armed):
                timer.fire_due()

    def _clear_response_deadline(self) -> None:
        if self._response_deadline is not None:
            self._response_deadline.clear()

    def _release_caller(self) -> None:
        if self._timer is not None and self._timer.waiting is not None:
            settle(self._timer.waiting)


def _held_reply(receiver: Receiver, held: _Round) -> bytes | None:
    """The reader callback, while a caller is held until its reply, for what the common
    case in `GapKeeper.heard` leaves: the reply's PDU, taken out of the buffer, if it is all there
    and valid; `_STILL_COMING` while it is still coming (the caller stays held); None:
    wake the caller, whose own reading decides (`ReplyReader`: a corrupt reply, one ended
    by a silence), going on with the record of arrivals the hold began.
    """
    frame = held.sending.frame
    received = receiver.received
    arrivals = receiver.arrivals
    pdu = None
    expected = held.plain_read
    if expected is not None and arrivals is not None and len(arrivals) == 2:
        # A read's reply, alone and in one piece, that came after bytes of no use, or
        # behind other bytes in the buffer (`heard` takes only a lone one directly).
        pdu = plain_read_reply(received, expected)
    if pdu is not None:
        received.clear()
        return pdu
    search = receiver.search(frame, receiver.echo_deadline(frame, held.sent))
    found = search.found
    if found is Found.PARTIAL or found is Found.NOTHING:
        # Still coming (adapters deliver in bursts), or so far only a glitch: the hold's
        # deadline, the response timeout, wakes the caller if it never completes.
        return _STILL_COMING
    if found is not Found.COMPLETE:
        return None
    try:
        reply = bytes(received[search.start : search.end])
        pdu = check_reply(frame, reply, crc_checked=True)
    except BadReply:
        return None  # the caller finds it too, counts it and drains the line
    receiver.take_reply(search, search.end)
    return pdu
