"""One RS-485 line driven from the event loop: the inter-frame gap, and each attempt on the wire.

The line is made of parts, each with one job:
- `gateway.bus.port`: the serial port, one interface for a tty the loop watches (every byte taken
  in as it arrives) and a pyserial URL read in the loop's thread pool;
- `gateway.bus.receiver`: the bytes heard and when, the reply found among them (a glitch or the
  adapter's echo before it skipped and counted), what the hardware does to replies;
- `gateway.bus.rts`: RTS switched around each request, for UARTs whose driver can't;
- `gateway.bus.gap_keeper`: the inter-frame gap before every frame, and the caller held through
  back-to-back transactions while the port's reader callback finishes each one;
- `gateway.bus.line_timer` with `gateway.bus.gap_lead`: the exact wake-up that ends a gap;
- `gateway.bus.reply_reader`: the rest of an attempt that its caller reads itself (a reply late,
  bad or partial, an echo, the drain after a timeout, a marker's answer).

This module puts them together for the bus: it opens and closes the port with its timer, starts
each attempt (`send_after_gap`, `transact`) and has its rest read (`finish`). Nothing blocks the
loop but the end of a gap, waited out on the clock after a wake-up that came a learnt lead early
(up to a few hundred microseconds, never more than 400), and no thread is involved: a
transaction costs the loop a wake-up when the reply arrives and one when the gap ends, which is
all the CPU it needs.

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
"""

from __future__ import annotations

from collections.abc import Callable

from gateway.bus.direction import DirectionMode
from gateway.bus.exchange import Exchange as Exchange
from gateway.bus.exchange import Sending as Sending
from gateway.bus.gap_keeper import GapKeeper
from gateway.bus.line_settings import LineSettings as LineSettings
from gateway.bus.line_timer import LineTimer
from gateway.bus.line_user import LineUser, OneFrame
from gateway.bus.port import Port, open_port
from gateway.bus.receiver import BURSTS_FROM_S as BURSTS_FROM_S
from gateway.bus.receiver import Receiver
from gateway.bus.reply_reader import ReplyReader
from gateway.bus.rts import RtsSwitch
from gateway.errors import PortError


class SerialLine:
    """Exact-timing access to one serial port from the running event loop. One user at a time."""

    def __init__(self, settings: LineSettings) -> None:
        self.settings = settings
        self.receiver = Receiver(settings)
        self.on_port_error: Callable[[], None] | None = None
        """Called when the port fails while nobody is reading it (an adapter unplugged)."""
        # Two hooks for redundancy (issue 48, `gateway.redundancy`), both None unless a second
        # gateway shares the line: nothing is called for them then.
        self.on_heard: Callable[[bytes], None] | None = None
        """Told of every read from the port before the line takes it in (set before `open`):
        the active gateway's watch for another master's frames."""
        self.on_open: Callable[[Port], None] | None = None
        """Given each port the line opens, before anything is written to it: the active
        gateway's gate in front of its writes, closed when another master is heard."""
        self._port: Port | None = None
        self._timer: LineTimer | None = None
        self._rts: RtsSwitch | None = None
        self._reader: ReplyReader | None = None
        self._gap = GapKeeper(settings, self.receiver, self._discard_pending)
        self.gap_lead = self._gap.gap_lead
        """How long before the gap's end the timer wakes the line (`gateway.bus.gap_lead`)."""
        self.queued: Callable[[], None] = self._gap.queued
        """A request was queued: `kick`, then `fire_due` (`GapKeeper.queued`); the gap
        keeper's own, bound once: no call through the line, once per request."""

    # What the receiver has seen, as metrics and the field tools read it off the line.

    @property
    def discarded_bytes(self) -> int:
        return self.receiver.discarded_bytes

    @property
    def garbage_bytes(self) -> int:
        """Bytes skipped before replies: glitches, noise (`invt_gateway_line_garbage_bytes`)."""
        return self.receiver.garbage_bytes

    @property
    def echoes(self) -> int:
        """Requests the adapter handed back although `echo: false` said it wouldn't."""
        return self.receiver.echoes

    @property
    def echo_detected(self) -> bool:
        """The adapter has handed back a request though `echo: false` says it doesn't echo."""
        return self.receiver.echoes > 0

    @property
    def longest_reply_silence_s(self) -> float:
        """The longest silence seen inside a reply: an adapter's burst delivery shows here."""
        return self.receiver.longest_reply_silence_s

    @property
    def busy_until(self) -> float:
        """When the line is quiet again: the last byte heard, or a broadcast's turnaround end."""
        return self.receiver.quiet_since

    @property
    def is_open(self) -> bool:
        return self._port is not None and self._port.open

    @property
    def failed(self) -> bool:
        """The port has failed; the next use raises PortError (and closes it)."""
        return self._port is not None and self._port.error is not None

    def open(self) -> None:
        """Open the port and start listening to it; call with the event loop running."""
        self.close()  # what a port that failed left behind: its timers
        heard = self._gap.heard
        told = self.on_heard
        if told is not None:
            take = heard

            def heard(data: bytes) -> None:
                told(data)
                take(data)

        port = open_port(self.settings, self.receiver, heard, self._port_failed)
        if self.on_open is not None:
            self.on_open(port)
        self._port = port
        self._timer = timer = LineTimer(port.loop)
        control = self.settings.direction
        if control is not None and control.mode is DirectionMode.RTS:
            self._rts = RtsSwitch(control, port, timer)
        self._gap.opened(port, timer, self._rts)
        self._reader = ReplyReader(self.settings, self.receiver, port, self._rts)
        self.receiver.opened(port.virtual)  # quiet from now: the first gap ends a gap later

    def close(self) -> None:
        self._rts = None
        self._reader = None
        if self._timer is not None:
            self._timer.close()
            self._timer = None
        self._gap.closed()
        if self._port is not None:
            self._port.close()

    def fire_due(self) -> None:
        """Act now on any gap of this loop's lines that has ended (`LineTimer.fire_due`)."""
        if self._timer is not None:
            self._timer.fire_due()

    def _require_port(self) -> Port:
        port = self._port
        if port is None:
            raise PortError(f"{self.settings.port} is not open")
        port.check()
        return port

    def _port_failed(self) -> None:
        if self.on_port_error is not None:
            self.on_port_error()

    # -- the gap, and the caller held through back-to-back transactions (`GapKeeper`) -------

    async def transact(self, frame: bytes, *, expect_reply: bool, timeout_s: float) -> Exchange:
        """Send `frame` after the inter-frame gap and, unless a broadcast, read and check its reply.

        Raises ReplyTimeout or BadReply (after draining the line), or PortError (port closed).
        """
        sending = await self.send_after_gap(OneFrame(frame))
        assert sending is not None  # the pick always has a frame
        return await self.finish(sending, expect_reply=expect_reply, timeout_s=timeout_s)

    async def send_after_gap(self, user: LineUser) -> Sending | None:
        """At the end of the inter-frame gap, ask `user` for a frame and start writing it
        (`GapKeeper.send_after_gap`: the gap, the lead, the caller held while replies come
        and while the line is idle)."""
        return await self._gap.send_after_gap(user)

    def kick(self) -> None:
        """A request was queued: an idle line sends it now (`GapKeeper.kick`)."""
        self._gap.kick()

    def _discard_pending(self) -> None:
        """Throw away bytes nobody asked for (noise, a reply later than every drain)."""
        port = self._require_port()
        self.receiver.arrivals = None  # a new attempt starts its own record
        port.discard_pending()

    # -- the rest of an attempt, read by the caller (`gateway.bus.reply_reader`) -------------

    async def finish(
        self,
        sending: Sending,
        *,
        expect_reply: bool,
        timeout_s: float,
        owed: tuple[bytes, ...] = (),
    ) -> Exchange:
        """The rest of an attempt begun by `send_after_gap`: the frame's tail, echo, reply
        (`ReplyReader.finish`: a frame answering one of `owed` is set aside, not taken).

        Raises ReplyTimeout or BadReply (after draining the line), or PortError.
        """
        reader = self._require_reader()
        return await reader.finish(
            sending, expect_reply=expect_reply, timeout_s=timeout_s, owed=owed
        )

    def _require_reader(self) -> ReplyReader:
        if self._reader is None:
            raise PortError(f"{self.settings.port} is not open")
        return self._reader
