"""The serial port of one RS-485 line, used from the bus's own thread only.

Why a thread and blocking calls: asyncio's selector rounds every timeout up to whole milliseconds,
so a 1.75 ms gap would become 2-3 ms and a 115200-baud line would lose a quarter of its capacity.
`select()` and `time.sleep()` in a dedicated thread keep the inter-frame gap to within tens of
microseconds, and the event loop never blocks on the port.

Timeouts, and which is which:
- `timeout_s` (response timeout): from the end of the request on the wire to the first byte of the
  reply. A drive answers after its own response delay (INVT P14.03, default 5 ms).
- `char_timeout_s` (inter-character timeout): silence inside a reply that ends it. A reply cut short
  is `truncated`; a reply of unknown length ends there. USB adapters deliver in bursts (FTDI latency
  timer 16 ms), so this is longer than t1.5.
- `drain_s`: after a timeout, how long to keep listening for a late reply before the next request,
  so it is never taken for the answer to the next one (RTU has no transaction id).
"""

from __future__ import annotations

import contextlib
import os
import select
import termios
import time
from dataclasses import dataclass

import serial

from gateway.errors import BadReply, PortError, ReplyTimeout
from gateway.modbus.functions import NEED_MORE, UNKNOWN_LENGTH, rtu_reply_length
from gateway.modbus.rtu import check_reply
from gateway.modbus.timing import CharacterFormat

# Stray bytes that keep coming for this long are noise on the line, not a frame: stop draining and
# let the next request take its chances rather than block the bus forever.
MAX_DRAIN_S = 1.0


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
    """Blocking, exact-timing access to one serial port. Not thread-safe: one thread owns it."""

    def __init__(self, settings: LineSettings) -> None:
        self.settings = settings
        self._port: serial.SerialBase | None = None
        self._fd: int | None = None
        self._quiet_since = 0.0
        self.discarded_bytes = 0

    @property
    def is_open(self) -> bool:
        return self._port is not None

    def open(self) -> None:
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
            self._fd = port.fileno()
        except Exception:  # URL ports (socket://, loop://) have no descriptor to select on
            self._fd = None
        with contextlib.suppress(Exception):
            port.reset_input_buffer()
        self._port = port
        self._quiet_since = time.monotonic()

    def close(self) -> None:
        port, self._port, self._fd = self._port, None, None
        if port is not None:
            with contextlib.suppress(Exception):
                port.close()

    # -- one attempt -------------------------------------------------------------------------

    def transact(self, frame: bytes, *, expect_reply: bool, timeout_s: float) -> Exchange:
        """Send `frame` after the inter-frame gap and, unless a broadcast, read and check its reply.

        Raises ReplyTimeout or BadReply (after draining the line), or PortError (port closed).
        """
        self.keep_gap()
        fmt = self.settings.char_format
        started = time.monotonic()
        gap = started - self._quiet_since
        self._write(frame)
        sent = started + fmt.wire_time_s(len(frame))
        if self.settings.echo:
            self._read_echo(frame, sent)
        if not expect_reply:
            self._quiet_since = sent + self.settings.turnaround_s
            return Exchange(None, gap, self._quiet_since - started)
        try:
            reply = self._read_reply(frame, sent + timeout_s)
            pdu = check_reply(frame, reply)
        except ReplyTimeout:
            self._drain(self.settings.drain_s)
            raise
        except BadReply:
            self._drain(0.0)
            raise
        finally:
            self._quiet_since = max(self._quiet_since, time.monotonic())
        return Exchange(pdu, gap, self._quiet_since - started)

    def keep_gap(self) -> None:
        """Wait until the line has been quiet for the gap; bytes arriving meanwhile restart it."""
        gap = self.settings.gap_s
        while True:
            self._discard_pending()
            wait = self._quiet_since + gap - time.monotonic()
            if wait <= 0:
                return
            time.sleep(wait)

    def _discard_pending(self) -> None:
        """Throw away bytes nobody asked for (noise, a reply later than every drain)."""
        while data := self._read_some(256, 0.0):
            self.discarded_bytes += len(data)
            self._quiet_since = time.monotonic()

    def _read_reply(self, frame: bytes, first_byte_deadline: float) -> bytes:
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
            remaining = deadline - time.monotonic()
            chunk = self._read_some(want, remaining) if remaining > 0 else b""
            if chunk:
                reply += chunk
                deadline = time.monotonic() + char_timeout
                continue
            if not reply:
                raise ReplyTimeout(f"no reply to {frame[:2].hex(' ')} within the response timeout")
            if expected == UNKNOWN_LENGTH:
                return bytes(reply)
            raise BadReply("truncated", f"reply stopped after {len(reply)} bytes", bytes(reply))

    def _read_echo(self, frame: bytes, sent: float) -> None:
        """Adapters without echo suppression hand back what we sent; it must match exactly."""
        echo = bytearray()
        deadline = sent + self.settings.char_timeout_s
        while len(echo) < len(frame):
            remaining = deadline - time.monotonic()
            chunk = self._read_some(len(frame) - len(echo), remaining) if remaining > 0 else b""
            if not chunk:
                break
            echo += chunk
        if bytes(echo) != frame:
            self._drain(0.0)
            raise BadReply("echo", f"echo {bytes(echo).hex(' ')} differs from what was sent")

    def _drain(self, wait_for_late_s: float) -> None:
        """Listen up to `wait_for_late_s` for a late frame, then until the line is quiet."""
        char_timeout = self.settings.char_timeout_s
        started = time.monotonic()
        deadline = started + max(wait_for_late_s, char_timeout)
        while True:
            now = time.monotonic()
            if now >= deadline or now - started > MAX_DRAIN_S:
                return
            data = self._read_some(256, deadline - now)
            if data:
                self.discarded_bytes += len(data)
                self._quiet_since = time.monotonic()
                # A late frame is arriving: follow it to its end, then stop.
                deadline = self._quiet_since + char_timeout

    # -- raw port access ---------------------------------------------------------------------

    def _write(self, frame: bytes) -> None:
        port = self._require_port()
        try:
            if self._fd is not None:
                view = memoryview(frame)
                # A frame takes its wire time to leave; an adapter that takes a second more
                # is wedged, and a bus thread stuck here would hold the line forever.
                deadline = time.monotonic() + self.settings.char_format.wire_time_s(len(frame)) + 1
                while view:
                    try:
                        written = os.write(self._fd, view)
                    except BlockingIOError:  # the port is non-blocking; its buffer is full
                        remaining = deadline - time.monotonic()
                        if remaining <= 0:
                            raise OSError(
                                "the port takes no more bytes (adapter wedged?)"
                            ) from None
                        select.select([], [self._fd], [], remaining)
                        continue
                    view = view[written:]
            else:
                port.write(frame)
        except (serial.SerialException, OSError, termios.error) as exc:
            self.close()
            raise PortError(f"write to {self.settings.port} failed: {exc}") from exc

    def _read_some(self, max_bytes: int, timeout_s: float) -> bytes:
        """Up to `max_bytes` that arrive within `timeout_s`; b"" when none do."""
        port = self._require_port()
        try:
            if self._fd is not None:
                ready, _, _ = select.select([self._fd], [], [], max(timeout_s, 0.0))
                if not ready:
                    return b""
                data = os.read(self._fd, max_bytes)
                if not data:
                    raise OSError("device reports data but returns none (unplugged?)")
                return data
            port.timeout = max(timeout_s, 0.0)
            return bytes(port.read(max_bytes))
        except (serial.SerialException, OSError, termios.error) as exc:
            self.close()
            raise PortError(f"read from {self.settings.port} failed: {exc}") from exc

    def _require_port(self) -> serial.SerialBase:
        if self._port is None:
            raise PortError(f"{self.settings.port} is not open")
        return self._port
