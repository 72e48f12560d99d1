"""The serial port of one RS-485 line, driven from the event loop.

The port's descriptor is watched by the loop all the time: every byte is taken in as it arrives,
with its arrival time, so the line knows when it last went quiet even between transactions (a late
reply, noise). Reads are served from that buffer; the inter-frame gap is kept with an exact timer
(`gateway.bus.line_timer`), not with asyncio's millisecond timeouts. Nothing here blocks the loop
but the end of a gap, waited out on the clock after a wake-up that came a learnt lead early
(`gateway.bus.gap_lead`; up to a few hundred microseconds, never more than 400), and no thread is
involved: a transaction costs the loop a wake-up when the reply arrives and one when the gap
ends, which is all the CPU it needs.

Timeouts, and which is which:
- `timeout_s` (response timeout): from the end of the request on the wire to the first byte of the
  reply. A drive answers after its own response delay (INVT P14.03, default 5 ms).
- `char_timeout_s` (inter-character timeout): silence that ends a reply whose length no rule gives
  (a function code the table doesn't know), and that ends a drain. A reply whose length its header
  gives is never ended by silence before the response deadline: adapters deliver received bytes in
  bursts (FTDI's latency timer: 16 ms; serial device servers pack bytes into TCP segments), so a
  silence inside a reply says nothing about the line. Such a reply that truly stops short is caught
  at that deadline, by its length and CRC. After the response deadline, a reply still arriving
  ends after `char_timeout_s` of silence.
- `drain_s`: after a timeout, how long to keep listening for a late reply before the next request,
  so it is never taken for the answer to the next one (RTU has no transaction id).

The reply is searched for among the bytes received, not assumed to start at the first one
(`gateway.modbus.reply_search`): a glitch byte from a transceiver switching on, or the request
echoed by an adapter without echo suppression, is skipped and counted, never trusted. The line
also watches what real hardware does to replies (the longest silence inside one, an echo where
`echo: false` says there is none) and says once in the log what to change.

Direction control for UARTs with an RS-485 transceiver (`gateway.bus.direction`): the kernel's
RS-485 mode, or RTS toggled by the line around each write.

Ports named by a pyserial URL (socket://, rfc2217://) have no descriptor to watch: their timed
reads run in the loop's thread pool instead, which is slower but exact enough for a device server
that sits behind a network anyway.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import logging
import os
import select
import termios
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import NamedTuple

import serial

from gateway.bus.direction import DirectionControl, DirectionMode, apply_kernel_mode, set_rts
from gateway.bus.gap_lead import GapLead, loop_spin_budget
from gateway.bus.hardware_hints import burst_hint, echo_hint
from gateway.bus.line_timer import LineTimer
from gateway.bus.wakeup import MovingDeadline, settle, woken_or_timeout
from gateway.errors import BadReply, PortError, ReplyTimeout
from gateway.modbus.functions import EXCEPTION_BIT
from gateway.modbus.reply_search import MIN_REPLY, Found, ReplySearch, search_reply
from gateway.modbus.rtu import MAX_FRAME, check_reply
from gateway.modbus.timing import CharacterFormat

log = logging.getLogger(__name__)

# Stray bytes that keep coming for this long are noise on the line, not a frame: stop draining and
# let the next request take its chances rather than block the bus forever.
MAX_DRAIN_S = 1.0
RECEIVE_CHUNK = 4096
MAX_BUFFERED = 4096
"""Bytes kept while nobody reads (a frame is at most 256): a babbling line can't fill memory."""
BURSTS_FROM_S = 0.005
"""A silence inside a reply longer than this (beyond its bytes' own wire time) means the adapter
delivers in bursts: worth a word in the log once. Clean USB adapters show well under 1 ms."""


@dataclass(frozen=True, slots=True)
class LineSettings:
    port: str
    char_format: CharacterFormat
    gap_s: float
    char_timeout_s: float
    drain_s: float
    turnaround_s: float
    echo: bool = False
    direction: DirectionControl | None = None
    """Who switches the RS-485 driver: None for adapters that do it themselves."""
    name: str = ""
    """The bus's name, for messages; the port's path when empty."""

    @property
    def where(self) -> str:
        return f"bus {self.name} ({self.port})" if self.name else self.port


# Immutable, and built per transaction: a NamedTuple costs a fraction of a frozen dataclass,
# whose __init__ goes through object.__setattr__ for every field.
class Sending(NamedTuple):
    """An attempt whose frame has started to go out."""

    frame: bytes
    started: float
    """When the first byte was handed to the port (`time.monotonic()`)."""
    gap_s: float
    """Silence kept before it (measured, not assumed)."""
    written: int
    """Bytes the port took at once; `finish` writes the rest."""
    write_at: float = 0.0
    """RTS direction control with a set-up delay: when `finish` may write the frame (the
    driver was switched on at `started`)."""


# A NamedTuple for the reason given at `Sending`.
class Exchange(NamedTuple):
    """What one attempt did on the wire."""

    reply_pdu: bytes | None
    """The reply's PDU, or None for a broadcast."""
    gap_s: float
    """Silence kept before the request (measured, not assumed)."""
    busy_s: float
    """Time the line was busy with this exchange: request, drive's delay, reply."""
    reply_heard_at: float = 0.0
    """When the reply's last byte arrived (`time.monotonic()`); 0.0 when not known (a broadcast,
    a URL port without arrival times)."""


# A NamedTuple for the reason given at `Sending`.
class Resynchronised(NamedTuple):
    """A resynchronisation's echo came back (`SerialLine.resynchronise`)."""

    exchange: Exchange
    """The echo's exchange (or a device's exception 01H to 08H)."""
    late: tuple[float, ...]
    """When each whole frame that came before the echo arrived: replies to older requests."""


Replied = Callable[[Sending, Exchange], None]
"""Told, in the port's reader callback, of an attempt whose whole and valid reply is there."""


@dataclass(slots=True)
class _Round:
    """One `send_after_gap` call: how it picks and sends, and what came of it for its caller."""

    pick: Callable[[], bytes | None]
    reply_within: Callable[[], float | None] | None
    replied: Replied | None
    outcome: list[Sending | Exception | None]
    """Empty until a frame went out (its Sending), nothing was picked (None) or that failed."""
    picked: bytes | None = None
    """A frame chosen before the gap's end that could not go out then (bytes came in the last
    microseconds of the gap, which starts again): it goes at the next gap's end, as a frame
    already on its way would, its transaction out of the queue meanwhile (a write queued then
    waits behind it; closing the bus answers it as the transaction being carried)."""

    def take_pick(self) -> bytes | None:
        """The frame to send now: the one chosen earlier, if any, else `pick`'s."""
        picked, self.picked = self.picked, None
        return picked if picked is not None else self.pick()


# A NamedTuple for the reason given at `Sending`.
class _Held(NamedTuple):
    """A caller held until its reply (`_hold_until_reply`): the attempt the reply is for."""

    sending: Sending
    round: _Round
    echo_by: float
    """A copy of the request complete before this is the adapter's echo (`_echo_deadline`)."""


def _echo_of(echo_request: bytes, reply: bytes) -> bytes:
    """The PDU of `reply` if it is the answer to this very 08H 0000 request: the request byte
    for byte (its fresh value included: an older echo of another value is a late reply, which
    check_reply's length rule alone would let through), or the device's exception to 08H."""
    pdu = check_reply(echo_request, reply)
    if reply != echo_request and not pdu[0] & EXCEPTION_BIT:
        raise BadReply("mismatch", f"echo {reply.hex(' ')} is not of this value", reply)
    return pdu


def _whole_frames(request: bytes, received: bytes | bytearray) -> list[bytes]:
    """The whole, sound frames among `received` (a reply to `request`, or anyone's), in order;
    what is between and after them is skipped."""
    frames = []
    while (search := search_reply(received, request)).found is Found.COMPLETE:
        frames.append(bytes(received[search.start : search.end]))
        received = received[search.end :]
    return frames


def _answers(request: bytes, received: bytes | bytearray) -> bool:
    """Is there a whole, sound reply to `request` among `received`?"""
    search = search_reply(received, request)
    if search.found is not Found.COMPLETE:
        return False
    try:
        check_reply(request, bytes(received[search.start : search.end]), crc_checked=True)
    except BadReply:
        return False
    return True


PTY_SLAVE_MAJORS = range(136, 144)
"""Linux's device numbers for pseudo-terminal slaves (/dev/pts/N)."""


def is_pseudo_terminal(port: str) -> bool:
    """True for a pty (or a link to one): a virtual line, such as the simulator's."""
    try:
        device = os.stat(port).st_rdev  # follows links such as /dev/serial/by-id/...
    except (OSError, ValueError):
        return False  # not a path: a pyserial URL, or not there (open() will say so)
    return os.major(device) in PTY_SLAVE_MAJORS


class SerialLine:
    """Exact-timing access to one serial port from the running event loop. One user at a time."""

    def __init__(self, settings: LineSettings) -> None:
        self.settings = settings
        self.discarded_bytes = 0
        self.garbage_bytes = 0
        """Bytes skipped before replies: glitches, noise (`invt_gateway_line_garbage_bytes`)."""
        self.echoes = 0
        """Requests the adapter handed back although `echo: false` said it wouldn't."""
        self.longest_reply_silence_s = 0.0
        """The longest silence seen inside a reply (beyond its bytes' wire time): an adapter's
        burst delivery shows here."""
        self._arrivals: list[tuple[int, float]] | None = None
        """While a reply is awaited: (buffer length after each read, its time)."""
        self._bursts_told = False
        self._virtual = False
        """The port is a pty: no wire, so no wire timing to judge an echo by."""
        self.on_port_error: Callable[[], None] | None = None
        """Called when the port fails while nobody is reading it (an adapter unplugged)."""
        self._port: serial.SerialBase | None = None
        self._fd: int | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._timer: LineTimer | None = None
        self._received = bytearray()
        self._quiet_since = 0.0
        self._error: PortError | None = None
        self._waiter: asyncio.Future[None] | None = None
        self._poll: select.poll | None = None
        self._holding = False
        """`send_after_gap`'s caller is held until the reply's first bytes, or the response
        timeout (`_response_deadline`)."""
        self._response_deadline: MovingDeadline | None = None
        """The held caller's response timeout: it wakes the caller, whose own reading then
        finds the reply missing or incomplete."""
        self._held: _Held | None = None
        """What the held caller sent, for the reader callback to finish the attempt itself."""
        self.gap_lead = GapLead(settings.gap_s)
        """How long before the gap's end the timer wakes the line (`gateway.bus.gap_lead`)."""
        self._learns_lead = False
        """The timer's wake-ups are exact (timerfd): the lead is learnt from them. Without a
        timerfd the loop's timer never fires early, and the lead stays 0."""

    @property
    def is_open(self) -> bool:
        return self._port is not None

    @property
    def failed(self) -> bool:
        """The port has failed; the next use raises PortError (and closes it)."""
        return self._error is not None

    def open(self) -> None:
        """Open the port and start listening to it; call with the event loop running."""
        loop = asyncio.get_running_loop()
        fmt = self.settings.char_format
        # A pty has no wire and no parity bit; Linux takes PARENB on one once and then refuses it
        # (EINVAL), so a virtual line that is opened again (a reopen, a field tool after a scan)
        # would fail. Timing still follows the configured format.
        virtual = is_pseudo_terminal(self.settings.port)
        parity = "N" if virtual else fmt.parity
        try:
            port = serial.serial_for_url(
                self.settings.port,
                baudrate=fmt.baudrate,
                parity=parity,
                stopbits=fmt.stopbits,
                bytesize=fmt.bytesize,
                timeout=0,
                write_timeout=2.0,
                exclusive=True,
            )
        except (serial.SerialException, OSError, ValueError, termios.error) as exc:
            raise PortError(f"cannot open {self.settings.port}: {exc}") from exc
        try:
            self._take_direction(port)
        except PortError:
            port.close()
            raise
        # FTDI adapters hold received bytes up to 16 ms unless asked not to; not every port can.
        with contextlib.suppress(Exception):
            port.set_low_latency_mode(True)
        try:
            fd: int | None = port.fileno()
        except Exception:  # URL ports (socket://, loop://) have no descriptor to watch
            fd = None
        with contextlib.suppress(Exception):
            port.reset_input_buffer()
        self._port, self._fd, self._loop = port, fd, loop
        self._virtual = virtual
        self._received.clear()
        self._error = None
        self._timer = LineTimer(loop)
        self._response_deadline = MovingDeadline(loop, self._wake)
        self._learns_lead = self._timer.exact
        self.gap_lead.budget = loop_spin_budget(loop)
        if fd is not None:
            loop.add_reader(fd, self._receive)
            self._poll = select.poll()
            self._poll.register(fd, select.POLLIN)
        self._quiet_since = time.monotonic()

    def _take_direction(self, port: serial.SerialBase) -> None:
        """Set the port up for the bus's RS-485 direction control, if any."""
        control = self.settings.direction
        if control is None:
            return
        where = self.settings.where
        if control.mode is DirectionMode.KERNEL:
            apply_kernel_mode(port, control, where)
        else:
            set_rts(port, not control.rts_level_for_tx, where)  # listening until a request

    @property
    def busy_until(self) -> float:
        """When the line is quiet again: the last byte heard, or a broadcast's turnaround end."""
        return self._quiet_since

    @property
    def echo_detected(self) -> bool:
        """The adapter has handed back a request though `echo: false` says it doesn't echo."""
        return self.echoes > 0

    def close(self) -> None:
        self._held = None
        port, self._port = self._port, None
        fd, self._fd = self._fd, None
        self._poll = None
        if fd is not None and self._loop is not None and not self._loop.is_closed():
            self._loop.remove_reader(fd)
        if self._timer is not None:
            self._timer.close()
            self._timer = None
        if self._response_deadline is not None:
            self._response_deadline.close()
            self._response_deadline = None
        if port is not None:
            with contextlib.suppress(Exception):
                port.close()
        self._wake()

    # -- one attempt -------------------------------------------------------------------------

    async def transact(self, frame: bytes, *, expect_reply: bool, timeout_s: float) -> Exchange:
        """Send `frame` after the inter-frame gap and, unless a broadcast, read and check its reply.

        Raises ReplyTimeout or BadReply (after draining the line), or PortError (port closed).
        """
        sending = await self.send_after_gap(lambda: frame)
        assert sending is not None  # the pick always has a frame
        return await self.finish(sending, expect_reply=expect_reply, timeout_s=timeout_s)

    async def send_after_gap(
        self,
        pick: Callable[[], bytes | None],
        reply_within: Callable[[], float | None] | None = None,
        replied: Replied | None = None,
    ) -> Sending | None:
        """At the end of the inter-frame gap, ask `pick` for a frame and start writing it.

        `pick` runs in the wake-up that ends the gap (inside the gap timer's callback), so the
        gap is not stretched by another pass of the event loop; that wake-up comes a learnt
        lead before the gap's end (`gateway.bus.gap_lead`, up to a few hundred microseconds),
        and the rest of the gap is waited out on the clock, so the frame goes out as the gap
        ends. None from `pick`: nothing to send now (returned as None). Bytes arriving during the
        gap restart it; a frame already chosen then goes at the new gap's end.

        `reply_within`, asked right after `pick`: how long the drive has to answer the frame
        just picked (None: no reply, or none to wait for here). The caller then resumes when
        the reply's first bytes come (or that time passes) instead of as the frame goes out:
        nothing is left to do between the two, and it saves the loop a pass per transaction.

        `replied`, with `reply_within`: when the reply is all there and valid as it comes in,
        the port's reader callback finishes the attempt itself and tells `replied`, keeps the
        gap and sends the next frame `pick` gives, the caller held all along: a busy line
        costs the loop no pass for the caller's coroutine. What the caller gets in the end is
        the attempt its own reading must finish (`finish`: a reply that is late, partial, bad
        or ended by a silence), or None once `pick` has nothing.
        """
        gap = self.settings.gap_s
        this = _Round(pick, reply_within, replied, [])
        while True:
            self._discard_pending()
            due = self._quiet_since + gap
            now = time.monotonic()
            if due <= now:
                frame = this.take_pick()
                return None if frame is None else self._send_frame(frame)
            assert self._timer is not None  # _discard_pending raised if the port is closed
            wake_at = self._wake_at(due)
            if wake_at <= now:  # within the lead already: wait out the rest, then look again
                self.gap_lead.wait_out(due)
                continue
            try:
                await self._timer.sleep_until(wake_at, partial(self._send_at_gap_end, this))
            finally:
                self._stop_holding()
            if this.outcome:
                outcome = this.outcome[0]
                if isinstance(outcome, Exception):
                    raise outcome  # in the caller's coroutine, not lost in a loop callback
                return outcome

    def _wake_at(self, gap_end: float) -> float:
        """When the timer should wake the line for a gap ending at `gap_end`: early by the
        learnt lead (which stays 0 where the timer has no timerfd: nothing is learnt there)."""
        return gap_end - self.gap_lead.lead_s

    def _send_at_gap_end(self, this: _Round, timed: bool = True) -> bool:
        """The gap timer's action: send as the gap ends, if the line is still quiet and usable.
        True: the caller stays held (`LineTimer.sleep_until`) while the reply comes
        (`_answer_held`).

        `timed`: called by the timer's wake-up (or `fire_due`), a lead before the gap's end
        (`gateway.bus.gap_lead`): the next frame is chosen now and the rest of the gap is
        waited out on the clock, and how early or late that was teaches the lead.
        """
        if self._port is None or self._error is not None or self._received:
            return False  # closed, failed or not quiet after all: `send_after_gap` looks again
        if self._fd is None:
            return False  # a URL port: only `_discard_pending_url` can tell if bytes came
        if self._bytes_waiting():
            self._quiet_since = time.monotonic()
            return False
        gap_end = self._quiet_since + self.settings.gap_s
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
            this.outcome.append(None)
            return False
        if timed and self._learns_lead:
            lead.ready(gap_end)
        elif early:
            lead.wait_out(gap_end)
        if early and self._bytes_waiting():
            # Bytes came while the frame was chosen and the gap waited out: the line was not
            # quiet, so the gap starts again, and the frame goes at its end.
            self._quiet_since = time.monotonic()
            this.picked = frame
            return False
        try:
            sending = self._send_frame(frame)
        except Exception as exc:
            this.outcome.append(exc)
            return False
        this.outcome.append(sending)
        if sending is None or this.reply_within is None or not self._waits_for_reply_only(sending):
            return False
        within_s = this.reply_within()
        if within_s is None:
            return False
        return self._hold_until_reply(sending, within_s, this)

    def _waits_for_reply_only(self, sending: Sending) -> bool:
        """Is all that `finish` would do for this attempt to wait for the reply? (The frame
        is out whole, no RTS to switch back, no echo to read first.)"""
        control = self.settings.direction
        return (
            sending.written == len(sending.frame)
            and not self.settings.echo
            and (control is None or control.mode is not DirectionMode.RTS)
        )

    def _hold_until_reply(self, sending: Sending, within_s: float, this: _Round) -> bool:
        assert self._timer is not None
        waiting = self._timer.waiting
        if waiting is None or self._waiter is not None:
            return False
        # The reader callback wakes whoever waits in `_waiter` (the held caller) when its reply
        # needs the caller's own reading; the response timeout does too, so a silent drive
        # still times out on time.
        self._waiter = waiting
        sent = sending.started + self.settings.char_format.wire_time_s(len(sending.frame))
        self._holding = True
        # Not on the gap timer: a timerfd write per transaction for a deadline that is almost
        # never reached costs more than the float stores of a moving deadline.
        assert self._response_deadline is not None
        self._response_deadline.set(sent + within_s)
        self._arrivals = [(len(self._received), sent)]  # what came, when: for echoes and bursts
        if this.replied is not None:
            self._held = _Held(sending, this, self._echo_deadline(sending.frame, sent))
        return True

    def _stop_holding(self) -> None:
        self._held = None
        if not self._holding:
            return
        self._holding = False
        # `_arrivals` stays: the caller's own reading goes on with the record the hold began (an
        # echo seen then is known for one by its time; a reply's silences are all measured).
        self._clear_response_deadline()
        if self._waiter is not None and self._waiter.done():
            self._waiter = None

    def _answer_held(self, held: _Held) -> bool:
        """The reader callback, while a caller is held until its reply: finish the attempt here
        if the reply is all there and valid. True: dealt with, the caller stays held (also
        while the reply is still coming); False: wake the caller, whose own reading decides
        (`_search_reply`: a corrupt reply, one ended by a silence), going on with the record
        of arrivals the hold began.
        """
        frame = held.sending.frame
        search = search_reply(
            self._received,
            frame,
            adapter_echoes=self.echo_detected or self._arrived_by(len(frame), held.echo_by),
        )
        found = search.found
        if found is Found.PARTIAL or found is Found.NOTHING:
            # Still coming (adapters deliver in bursts), or so far only a glitch: the hold's
            # deadline, the response timeout, wakes the caller if it never completes.
            return True
        if found is not Found.COMPLETE:
            return False
        try:
            reply = bytes(self._received[search.start : search.end])
            pdu = check_reply(frame, reply, crc_checked=True)
        except BadReply:
            return False  # the caller finds it too, counts it and drains the line
        self._take_reply(search, search.end)
        self._end_hold()
        sending, this = held.sending, held.round
        this.outcome.clear()
        exchange = Exchange(
            pdu, sending.gap_s, self._quiet_since - sending.started, self._quiet_since
        )
        try:
            assert this.replied is not None
            this.replied(sending, exchange)
            self._keep_gap(this)
        except Exception as exc:  # in the caller's coroutine, not lost in the reader callback
            this.outcome[:] = [exc]
            self._release_caller()
        return True

    def _end_hold(self) -> None:
        """The held attempt is over: its caller stays held, now only by the gap timer."""
        self._held = None
        self._arrivals = None
        self._holding = False
        self._clear_response_deadline()
        self._waiter = None

    def _clear_response_deadline(self) -> None:
        if self._response_deadline is not None:
            self._response_deadline.clear()

    def _keep_gap(self, this: _Round) -> None:
        """What `send_after_gap`'s loop does next, done here for a caller that stays held:
        keep the gap after the reply just taken and send the next frame at its end."""
        if self._received:  # what came after the reply: nobody asked for it
            self.discarded_bytes += len(self._received)
            self._received.clear()
        # Not `_discard_pending`: the port was read this very callback, and bytes that come
        # during the gap are seen at its end (`_send_at_gap_end`), which starts it again.
        timer = self._timer
        if self._port is None or self._error is not None or timer is None:
            self._release_caller()  # its own loop finds out what became of the port
            return
        due = self._quiet_since + self.settings.gap_s
        wake_at = self._wake_at(due)
        if wake_at > time.monotonic():
            if timer.rearm(wake_at, partial(self._send_at_gap_end, this)):
                return
        elif self._send_at_gap_end(this, timed=False):
            return
        self._release_caller()  # the caller's loop takes it from here (`outcome` says what)

    def _release_caller(self) -> None:
        if self._timer is not None and self._timer.waiting is not None:
            settle(self._timer.waiting)

    async def finish(self, sending: Sending, *, expect_reply: bool, timeout_s: float) -> Exchange:
        """The rest of an attempt begun by `send_after_gap`: the frame's tail, echo, reply."""
        frame, started = sending.frame, sending.started
        sent = await self._complete_request(sending)
        if not expect_reply:
            self._quiet_since = max(self._quiet_since, sent + self.settings.turnaround_s)
            return Exchange(None, sending.gap_s, self._quiet_since - started)
        try:
            reply = await self._read_reply(frame, sent, sent + timeout_s)
            pdu = check_reply(frame, reply)
        except ReplyTimeout as exc:
            drained = await self._drain(self.settings.drain_s)
            if _answers(frame, drained):  # the reply came within the drain: nothing in flight
                raise ReplyTimeout(str(exc), exc.received, late=(self._quiet_since,)) from None
            raise
        except BadReply:
            await self._drain(0.0)
            raise
        finally:
            if self._fd is None:  # no arrival times without a descriptor: now is the safe bet
                self._quiet_since = max(self._quiet_since, time.monotonic())
        heard_at = self._quiet_since if self._fd is not None else 0.0
        return Exchange(pdu, sending.gap_s, self._quiet_since - started, heard_at)

    async def resynchronise(self, sending: Sending, *, timeout_s: float) -> Resynchronised:
        """The rest of an attempt whose frame is a diagnostic echo (08H 0000) carrying a fresh
        value, sent to a drive that may still owe replies to requests that timed out.

        A drive answers its requests in order, so every whole frame that comes before the echo
        of this very value is a reply nobody waits for any more: it is set aside and returned,
        never taken for an answer, and once the echo is back nothing older is in flight. A
        device without 08H answers exception 01H, which ends the wait just as well: it comes
        in order too. Raises ReplyTimeout when the echo doesn't come within `timeout_s` (the
        drive is still busy with older requests, or gone), BadReply for a corrupt frame.
        """
        frame, started = sending.frame, sending.started
        sent = await self._complete_request(sending)
        deadline = sent + timeout_s
        late: list[float] = []
        try:
            while True:
                reply = await self._read_reply(frame, sent, deadline)
                try:
                    pdu = _echo_of(frame, reply)
                except BadReply as exc:
                    if exc.kind in ("crc", "truncated"):
                        raise
                    late.append(self._quiet_since)  # whole and sound, but not this echo
                    continue
                break
        except ReplyTimeout as exc:
            # What the drain hears is read too: more late replies, or the echo itself.
            echo = None
            for whole in _whole_frames(frame, await self._drain(self.settings.drain_s)):
                try:
                    echo = _echo_of(frame, whole)
                except BadReply:
                    late.append(self._quiet_since)
            if echo is None:
                raise ReplyTimeout(str(exc), exc.received, late=tuple(late)) from None
            pdu = echo
        except BadReply:
            # A corrupt frame: the echo may be in it, or still to come; the next attempt
            # resynchronises again with a fresh value.
            await self._drain(0.0)
            raise
        finally:
            if self._fd is None:
                self._quiet_since = max(self._quiet_since, time.monotonic())
        heard_at = self._quiet_since if self._fd is not None else 0.0
        exchange = Exchange(pdu, sending.gap_s, self._quiet_since - started, heard_at)
        return Resynchronised(exchange, tuple(late))

    async def _complete_request(self, sending: Sending) -> float:
        """Put the rest of `sending`'s frame on the wire (and read back its echo, where the
        adapter is said to echo); when its last character has left the wire."""
        frame, started = sending.frame, sending.started
        control = self.settings.direction
        if control is not None and control.mode is DirectionMode.RTS:
            sent = await self._finish_rts(sending, control)
        else:
            if sending.written < len(frame):
                await self._write(frame[sending.written :])
            sent = started + self.settings.char_format.wire_time_s(len(frame))
        # Our own frame holds the line until its last character has left; bytes heard since it
        # went out (the caller was held until the reply began) tell the line's last sound.
        if not self._received:
            self._quiet_since = max(self._quiet_since, sent)
        if self.settings.echo:
            await self._read_echo(frame, sent)
        return sent

    def _send_frame(self, frame: bytes) -> Sending:
        started = time.monotonic()
        gap = started - self._quiet_since
        control = self.settings.direction
        if control is not None and control.mode is DirectionMode.RTS:
            return self._start_rts(frame, started, gap, control)
        return Sending(frame, started, gap, self._write_now(frame))

    # -- RTS direction control -----------------------------------------------------------------

    def _start_rts(
        self, frame: bytes, started: float, gap: float, control: DirectionControl
    ) -> Sending:
        """Switch the driver on; write at once unless the transceiver needs a set-up delay."""
        self._set_rts(control.rts_level_for_tx)
        if control.delay_before_tx_s > 0:
            return Sending(frame, started, gap, 0, write_at=started + control.delay_before_tx_s)
        self._write_whole(frame)
        return Sending(frame, started, gap, len(frame))

    async def _finish_rts(self, sending: Sending, control: DirectionControl) -> float:
        """Write (after the set-up delay), wait for the UART to drain, hold, release the driver.

        Returns when the last bit left (the drain), the moment the response timeout counts from.
        """
        assert self._timer is not None
        if sending.written < len(sending.frame):
            await self._timer.sleep_until(sending.write_at)
            self._write_whole(sending.frame)
        wire_s = self.settings.char_format.wire_time_s(len(sending.frame))
        await self._drained(wire_s + 1.0)
        sent = time.monotonic()
        if control.delay_after_tx_s > 0:
            await self._timer.sleep_until(sent + control.delay_after_tx_s)
        self._set_rts(not control.rts_level_for_tx)
        return sent

    def _set_rts(self, level: bool) -> None:
        try:
            set_rts(self._require_port(), level, self.settings.where)
        except PortError:
            self.close()
            raise

    def _write_whole(self, frame: bytes) -> None:
        """The whole frame through pyserial (RTS mode: the port's own write, then its drain)."""
        port = self._require_port()
        try:
            port.write(frame)
        except (serial.SerialException, OSError, termios.error) as exc:
            self.close()
            raise PortError(f"write to {self.settings.port} failed: {exc}") from exc

    async def _drained(self, within_s: float) -> None:
        """Wait until the UART has sent its last bit (tcdrain blocks: a worker thread does it)."""
        port = self._require_port()
        assert self._loop is not None
        try:
            await asyncio.wait_for(self._loop.run_in_executor(None, port.flush), within_s)
        except TimeoutError:
            self.close()
            wedged = f"{self.settings.port} doesn't finish sending (adapter wedged?)"
            raise PortError(wedged) from None
        except (serial.SerialException, OSError, termios.error) as exc:
            self.close()
            raise PortError(f"drain of {self.settings.port} failed: {exc}") from exc

    def _discard_pending(self) -> None:
        """Throw away bytes nobody asked for (noise, a reply later than every drain)."""
        self._require_port()
        self._arrivals = None  # a new attempt starts its own record
        if self._fd is None:
            self._discard_pending_url()
            return
        if self._received:
            self.discarded_bytes += len(self._received)
            self._received.clear()
        if self._bytes_waiting():
            self._quiet_since = time.monotonic()  # the line is not quiet: the gap starts again

    def _bytes_waiting(self) -> bool:
        """Bytes the kernel holds that the loop hasn't taken in yet.

        The loop runs callbacks in the order they were queued: the bus (or the gap timer) may
        run before the reader callback for bytes that came in the same wake-up. They count:
        a frame must not go out less than t3.5 after them, nor they be taken for its reply.
        """
        return self._poll is not None and bool(self._poll.poll(0))

    async def _read_reply(self, frame: bytes, sent: float, response_deadline: float) -> bytes:
        """Find the reply to `frame` among the bytes that arrive, and return exactly it.

        Bytes before the reply that can't start it (a glitch, the adapter's echo) are skipped;
        bytes after it stay for `_discard_pending`. `check_reply` judges what is returned.
        """
        if self._arrivals is None:  # else: kept since the caller was held (`_hold_until_reply`)
            self._arrivals = [(len(self._received), self._quiet_since)]
        # A reply can't be complete before the request has left the wire and the reply has
        # crossed it: a copy of the request complete sooner is the adapter's echo (05H, 06H and
        # 08H replies are copies too; time tells them apart where the bytes can't). Not on a pty:
        # a virtual line has no wire, and a peer behind it may answer at once.
        echo_by = self._echo_deadline(frame, sent)
        try:
            return await self._search_reply(frame, response_deadline, echo_by)
        finally:
            self._arrivals = None

    def _echo_deadline(self, frame: bytes, sent: float) -> float:
        """A copy of `frame` complete before this moment is the adapter's echo, not a reply."""
        if self._virtual:
            return 0.0
        return sent + self.settings.char_format.wire_time_s(len(frame))

    async def _search_reply(self, frame: bytes, response_deadline: float, echo_by: float) -> bytes:
        char_timeout = self.settings.char_timeout_s
        wire_time = self.settings.char_format.wire_time_s
        # However the bytes trickle in, one attempt ends: a babbling line can't hold the bus.
        give_up = response_deadline + wire_time(MAX_FRAME) + char_timeout
        while True:
            seen = len(self._received)
            if not seen and await self._more_bytes(0, min(response_deadline, give_up)):
                continue  # the usual start: nothing to search until the first bytes come
            echoes = self.echo_detected or self._arrived_by(len(frame), echo_by)
            search = search_reply(self._received, frame, adapter_echoes=echoes)
            found = search.found
            if found is Found.COMPLETE or found is Found.CORRUPT:
                return self._take_reply(search, search.end)
            if found is Found.SILENCE_ENDS:
                deadline = self._quiet_since + char_timeout
            elif found is Found.PARTIAL:
                missing = search.end - seen if search.end else 3
                # Not ended by a silence before the response deadline: bursts cut replies.
                deadline = max(
                    response_deadline, self._quiet_since + char_timeout + wire_time(missing)
                )
            else:
                deadline = response_deadline
            if await self._more_bytes(seen, min(deadline, give_up)):
                continue
            return self._reply_at_deadline(frame, search)

    def _reply_at_deadline(self, frame: bytes, search: ReplySearch) -> bytes:
        """Nothing more came in time: the reply as far as it is, or why there is none."""
        received = self._received
        if search.found is Found.SILENCE_ENDS:
            return self._take_reply(search, len(received))
        if search.found is Found.PARTIAL:
            # The candidate never completed; a frame further on may have (the candidate was a
            # glitch that happened to look like the start of a reply).
            later = search_reply(
                received, frame, adapter_echoes=self.echo_detected, after=search.start
            )
            if later.found is Found.COMPLETE:
                return self._take_reply(later, later.end)
            partial = bytes(received[search.start :])
            raise BadReply("truncated", f"reply stopped after {len(partial)} bytes", partial)
        noise = bytes(received[search.echo :])
        if len(noise) >= MIN_REPLY:
            what = f"{len(noise)} bytes came, none of them a reply: {noise.hex(' ')}"
            raise BadReply("noise", what, noise)
        # A glitch byte or two is not an answer: the drive is silent as far as anyone can tell.
        raise ReplyTimeout(f"no reply to {frame[:2].hex(' ')} within the response timeout", noise)

    def _arrived_by(self, count: int, moment: float) -> bool:
        """Had the first `count` bytes of this read arrived before `moment`?"""
        for end, at in self._arrivals or ():
            if end >= count:
                return at < moment
        return False

    def _take_reply(self, search: ReplySearch, end: int) -> bytes:
        """Take `received[search.start:end]` as the reply: count what came before it."""
        if search.garbage:
            self.garbage_bytes += search.garbage
        if search.echo:
            self._echo_found()
        reply = bytes(self._received[search.start : end])
        self._note_silences(search.start, end)
        del self._received[:end]
        return reply

    def _note_silences(self, start: int, end: int) -> None:
        """The longest silence inside the reply at `start:end`, from the arrival times."""
        arrivals = self._arrivals
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

    async def _more_bytes(self, seen: int, deadline: float) -> bool:
        """Wait until more than `seen` bytes are buffered (True) or `deadline` passes (False)."""
        while len(self._received) <= seen:
            if self._fd is None:
                data = await self._read_some_url(256, deadline)
                if not data:
                    return False
                self._received += data
                if self._arrivals is not None:
                    self._arrivals.append((len(self._received), self._quiet_since))
                return True
            if not await self._woken_before(deadline):
                return False
        return True

    async def _woken_before(self, deadline: float) -> bool:
        """Wait until the reader callback has news (bytes, or the port failed) or `deadline`
        passes (False at once if it has). Response and character timeouts need no
        sub-millisecond precision: call_later does."""
        self._require_port()  # failed while the caller was held: say so now, not at the timeout
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            return False
        assert self._loop is not None
        waiter = self._waiter = self._loop.create_future()
        try:
            await woken_or_timeout(waiter, remaining)
        finally:
            if self._waiter is waiter:
                self._waiter = None
        self._require_port()
        return True

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
                self.discarded_bytes += len(data)
                if len(drained) < MAX_FRAME:
                    drained += data
                # A late frame is arriving: follow it to its end, then stop.
                deadline = self._quiet_since + char_timeout

    # -- the port ----------------------------------------------------------------------------

    def _receive(self) -> None:
        """The loop's reader callback: take in what arrived, note when, wake a reader."""
        assert self._fd is not None
        try:
            data = os.read(self._fd, RECEIVE_CHUNK)
            # Called only when the loop saw the port readable, and nothing else reads it: a
            # serial port that is readable yet gives nothing has gone (pyserial reads it so too).
            if not data:
                raise OSError("device reports data but returns none (unplugged?)")
        except BlockingIOError:
            return
        except OSError as exc:
            self._fail(PortError(f"read from {self.settings.port} failed: {exc}"))
            return
        self._received += data
        now = self._quiet_since = time.monotonic()
        if len(self._received) > MAX_BUFFERED:
            excess = len(self._received) - MAX_BUFFERED
            self.discarded_bytes += excess
            del self._received[:excess]
            if self._arrivals is not None:
                self._arrivals.clear()  # offsets moved; the silence measure starts again
        if self._arrivals is not None:
            self._arrivals.append((len(self._received), now))
        held = self._held
        if held is None or not self._answer_held(held):
            self._held = None  # the caller's own reading takes it from here
            self._wake()
        self.fire_due()  # another line's gap that ended while this pass ran

    def fire_due(self) -> None:
        """Act now on any gap of this loop's lines that has ended (`LineTimer.fire_due`)."""
        if self._timer is not None:
            self._timer.fire_due()

    def _fail(self, error: PortError) -> None:
        """The port is gone: stop watching it (a dead descriptor is readable forever)."""
        self._error = error
        if self._fd is not None and self._loop is not None:
            self._loop.remove_reader(self._fd)
        if self._waiter is None and self.on_port_error is not None:
            self.on_port_error()
        self._wake()

    def _wake(self) -> None:
        waiter = self._waiter
        if waiter is not None and not waiter.done():
            waiter.set_result(None)

    async def _read_some(self, max_bytes: int, deadline: float) -> bytes:
        """Up to `max_bytes` that arrive before `deadline` (monotonic); b"" when none do."""
        self._require_port()
        if self._fd is None:
            return await self._read_some_url(max_bytes, deadline)
        if not self._received and not await self._woken_before(deadline):
            return b""
        data = bytes(self._received[:max_bytes])
        del self._received[:max_bytes]
        return data

    def _write_now(self, frame: bytes) -> int:
        """Write what the port takes without waiting; how many bytes that was."""
        port = self._require_port()
        try:
            if self._fd is None:
                port.write(frame)
                return len(frame)
            try:
                return os.write(self._fd, frame)
            except BlockingIOError:  # the port's buffer is full: `finish` waits for room
                return 0
        except (serial.SerialException, OSError, termios.error) as exc:
            self.close()
            raise PortError(f"write to {self.settings.port} failed: {exc}") from exc

    async def _write(self, frame: bytes) -> None:
        port = self._require_port()
        try:
            if self._fd is None:
                port.write(frame)
                return
            view = memoryview(frame)
            # A frame takes its wire time to leave; an adapter that takes a second more is
            # wedged, and a bus stuck here would hold the line forever.
            deadline = time.monotonic() + self.settings.char_format.wire_time_s(len(frame)) + 1
            while view:
                try:
                    written = os.write(self._fd, view)
                except BlockingIOError:  # the port is non-blocking; its buffer is full
                    if not await self._writable(deadline):
                        raise OSError("the port takes no more bytes (adapter wedged?)") from None
                    continue
                view = view[written:]
        except (serial.SerialException, OSError, termios.error) as exc:
            self.close()
            raise PortError(f"write to {self.settings.port} failed: {exc}") from exc

    async def _writable(self, deadline: float) -> bool:
        assert self._loop is not None
        assert self._fd is not None
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            return False
        waiter: asyncio.Future[None] = self._loop.create_future()
        self._loop.add_writer(self._fd, settle, waiter)
        try:
            await woken_or_timeout(waiter, remaining)
        finally:
            if self._fd is not None:
                self._loop.remove_writer(self._fd)
        return time.monotonic() < deadline

    def _require_port(self) -> serial.SerialBase:
        if self._error is not None:
            error = self._error
            self.close()
            self._error = None
            raise error
        if self._port is None:
            raise PortError(f"{self.settings.port} is not open")
        return self._port

    # -- ports without a descriptor (pyserial URLs) -------------------------------------------

    def _discard_pending_url(self) -> None:
        port = self._require_port()
        try:
            port.timeout = 0
            while data := port.read(256):
                self.discarded_bytes += len(data)
                self._quiet_since = time.monotonic()
        except (serial.SerialException, OSError) as exc:
            self.close()
            raise PortError(f"read from {self.settings.port} failed: {exc}") from exc

    async def _read_some_url(self, max_bytes: int, deadline: float) -> bytes:
        port = self._require_port()
        assert self._loop is not None

        def read() -> bytes:
            port.timeout = max(deadline - time.monotonic(), 0.0)
            return bytes(port.read(max_bytes))

        try:
            data = await self._loop.run_in_executor(None, read)
        except (serial.SerialException, OSError) as exc:
            self.close()
            raise PortError(f"read from {self.settings.port} failed: {exc}") from exc
        if data:
            self._quiet_since = time.monotonic()
        return data
