"""The serial port of one RS-485 line, driven from the event loop.

The port's descriptor is watched by the loop all the time: every byte is taken in as it arrives,
with its arrival time, so the line knows when it last went quiet even between transactions (a late
reply, noise). Reads are served from that buffer; the inter-frame gap is kept with an exact timer
(`gateway.bus.line_timer`), not with asyncio's millisecond timeouts. Nothing here blocks the loop,
and no thread is involved: a transaction costs the loop a wake-up when the reply arrives and one
when the gap ends, which is all the CPU it needs.

Timeouts, and which is which:
- `timeout_s` (response timeout): from the end of the request on the wire to the first byte of the
  reply. A drive answers after its own response delay (INVT P14.03, default 5 ms).
- `char_timeout_s` (inter-character timeout): silence inside a reply that ends it. A reply cut short
  is `truncated`; a reply of unknown length ends there. USB adapters deliver in bursts (FTDI latency
  timer 16 ms), so this is longer than t1.5.
- `drain_s`: after a timeout, how long to keep listening for a late reply before the next request,
  so it is never taken for the answer to the next one (RTU has no transaction id).

Ports named by a pyserial URL (socket://, rfc2217://) have no descriptor to watch: their timed
reads run in the loop's thread pool instead, which is slower but exact enough for a device server
that sits behind a network anyway.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import select
import termios
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial

import serial

from gateway.bus.line_timer import LineTimer
from gateway.bus.wakeup import settle, woken_or_timeout
from gateway.errors import BadReply, PortError, ReplyTimeout
from gateway.modbus.functions import NEED_MORE, UNKNOWN_LENGTH, rtu_reply_length
from gateway.modbus.rtu import check_reply
from gateway.modbus.timing import CharacterFormat

# Stray bytes that keep coming for this long are noise on the line, not a frame: stop draining and
# let the next request take its chances rather than block the bus forever.
MAX_DRAIN_S = 1.0
RECEIVE_CHUNK = 4096
MAX_BUFFERED = 4096
"""Bytes kept while nobody reads (a frame is at most 256): a babbling line can't fill memory."""


@dataclass(frozen=True, slots=True)
class LineSettings:
    port: str
    char_format: CharacterFormat
    gap_s: float
    char_timeout_s: float
    drain_s: float
    turnaround_s: float
    echo: bool = False


@dataclass(frozen=True, slots=True)
class Sending:
    """An attempt whose frame has started to go out."""

    frame: bytes
    started: float
    """When the first byte was handed to the port (`time.monotonic()`)."""
    gap_s: float
    """Silence kept before it (measured, not assumed)."""
    written: int
    """Bytes the port took at once; `finish` writes the rest."""


@dataclass(frozen=True, slots=True)
class Exchange:
    """What one attempt did on the wire."""

    reply_pdu: bytes | None
    """The reply's PDU, or None for a broadcast."""
    gap_s: float
    """Silence kept before the request (measured, not assumed)."""
    busy_s: float
    """Time the line was busy with this exchange: request, drive's delay, reply."""


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
        parity = "N" if is_pseudo_terminal(self.settings.port) else fmt.parity
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
        self._received.clear()
        self._error = None
        self._timer = LineTimer(loop)
        if fd is not None:
            loop.add_reader(fd, self._receive)
            self._poll = select.poll()
            self._poll.register(fd, select.POLLIN)
        self._quiet_since = time.monotonic()

    def close(self) -> None:
        port, self._port = self._port, None
        fd, self._fd = self._fd, None
        self._poll = None
        if fd is not None and self._loop is not None and not self._loop.is_closed():
            self._loop.remove_reader(fd)
        if self._timer is not None:
            self._timer.close()
            self._timer = None
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

    async def send_after_gap(self, pick: Callable[[], bytes | None]) -> Sending | None:
        """At the end of the inter-frame gap, ask `pick` for a frame and start writing it.

        `pick` runs in the very wake-up that ends the gap (inside the gap timer's callback), so
        the gap is not stretched by another pass of the event loop: it chooses the request at
        the last possible moment and the frame goes out at once. None from `pick`: nothing to
        send now (returned as None). Bytes arriving during the gap restart it.
        """
        gap = self.settings.gap_s
        while True:
            self._discard_pending()
            due = self._quiet_since + gap
            if due <= time.monotonic():
                return self._send_now(pick)
            picked: list[Sending | Exception | None] = []
            assert self._timer is not None  # _discard_pending raised if the port is closed
            await self._timer.sleep_until(due, partial(self._send_at_gap_end, pick, picked))
            if picked:
                if isinstance(picked[0], Exception):
                    raise picked[0]  # in the caller's coroutine, not lost in a loop callback
                return picked[0]

    def _send_at_gap_end(
        self, pick: Callable[[], bytes | None], picked: list[Sending | Exception | None]
    ) -> None:
        """The gap timer's action: send now, if the line is still quiet and usable."""
        if self._port is None or self._error is not None or self._received:
            return  # closed, failed or not quiet after all: `send_after_gap` looks again
        if self._fd is None:
            return  # a URL port: only `_discard_pending_url` can tell if bytes came meanwhile
        if self._bytes_waiting():
            self._quiet_since = time.monotonic()
            return
        if self._quiet_since + self.settings.gap_s > time.monotonic():
            return
        try:
            picked.append(self._send_now(pick))
        except Exception as exc:
            picked.append(exc)

    async def finish(self, sending: Sending, *, expect_reply: bool, timeout_s: float) -> Exchange:
        """The rest of an attempt begun by `send_after_gap`: the frame's tail, echo, reply."""
        frame, started = sending.frame, sending.started
        if sending.written < len(frame):
            await self._write(frame[sending.written :])
        sent = started + self.settings.char_format.wire_time_s(len(frame))
        # Our own frame holds the line until its last character has left.
        self._quiet_since = max(self._quiet_since, sent)
        if self.settings.echo:
            await self._read_echo(frame, sent)
        if not expect_reply:
            self._quiet_since = max(self._quiet_since, sent + self.settings.turnaround_s)
            return Exchange(None, sending.gap_s, self._quiet_since - started)
        try:
            reply = await self._read_reply(frame, sent + timeout_s)
            pdu = check_reply(frame, reply)
        except ReplyTimeout:
            await self._drain(self.settings.drain_s)
            raise
        except BadReply:
            await self._drain(0.0)
            raise
        finally:
            if self._fd is None:  # no arrival times without a descriptor: now is the safe bet
                self._quiet_since = max(self._quiet_since, time.monotonic())
        return Exchange(pdu, sending.gap_s, self._quiet_since - started)

    def _send_now(self, pick: Callable[[], bytes | None]) -> Sending | None:
        frame = pick()
        if frame is None:
            return None
        started = time.monotonic()
        gap = started - self._quiet_since
        return Sending(frame, started, gap, self._write_now(frame))

    def _discard_pending(self) -> None:
        """Throw away bytes nobody asked for (noise, a reply later than every drain)."""
        self._require_port()
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

    async def _read_reply(self, frame: bytes, first_byte_deadline: float) -> bytes:
        """Read exactly one reply, ending by its expected length (or on silence if unknown)."""
        reply = bytearray()
        deadline = first_byte_deadline
        char_timeout = self.settings.char_timeout_s
        while True:
            expected = rtu_reply_length(reply, len(frame))
            if expected == NEED_MORE:
                want = (3 if len(reply) >= 2 else 2) - len(reply)
            elif expected == UNKNOWN_LENGTH:
                want = 256
            elif len(reply) >= expected:
                return bytes(reply)
            else:
                want = expected - len(reply)
            chunk = await self._read_some(want, deadline)
            if chunk:
                reply += chunk
                deadline = self._quiet_since + char_timeout
                continue
            if not reply:
                raise ReplyTimeout(f"no reply to {frame[:2].hex(' ')} within the response timeout")
            if expected == UNKNOWN_LENGTH:
                return bytes(reply)
            raise BadReply("truncated", f"reply stopped after {len(reply)} bytes", bytes(reply))

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

    async def _drain(self, wait_for_late_s: float) -> None:
        """Listen up to `wait_for_late_s` for a late frame, then until the line is quiet."""
        char_timeout = self.settings.char_timeout_s
        started = time.monotonic()
        deadline = started + max(wait_for_late_s, char_timeout)
        while True:
            now = time.monotonic()
            if now >= deadline or now - started > MAX_DRAIN_S:
                return
            data = await self._read_some(256, deadline)
            if data:
                self.discarded_bytes += len(data)
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
        self._quiet_since = time.monotonic()
        if len(self._received) > MAX_BUFFERED:
            excess = len(self._received) - MAX_BUFFERED
            self.discarded_bytes += excess
            del self._received[:excess]
        self._wake()

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
        if not self._received:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return b""
            assert self._loop is not None
            waiter = self._waiter = self._loop.create_future()
            # Response and character timeouts need no sub-millisecond precision: call_later.
            try:
                await woken_or_timeout(waiter, remaining)
            finally:
                if self._waiter is waiter:
                    self._waiter = None
            self._require_port()
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
