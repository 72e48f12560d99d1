"""The serial port of one line, behind one interface for both kinds of port.

- `TtyPort`, a serial device with a descriptor: the event loop watches it all the time, and its
  reader callback takes every byte in as it arrives (into the line's `Receiver`, which notes
  when), then tells the line. Writes go straight to the non-blocking descriptor.
- `UrlPort`, a port named by a pyserial URL (socket://, rfc2217://): there is no descriptor to
  watch, so bytes are read when the line waits for them, in the loop's thread pool instead. That
  is slower, but exact enough for a device server that sits behind a network anyway.

Whoever waits for bytes (`Port.wait`) is woken by them, by the port failing, or by its deadline.
A port that fails raises PortError, naming it, from the call that found out, and closes itself:
the bus reopens the line.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import select
import termios
import time
from abc import ABC, abstractmethod
from collections.abc import Callable

import serial

from gateway.bus.direction import DirectionMode, apply_kernel_mode, set_rts
from gateway.bus.line_settings import LineSettings
from gateway.bus.receiver import Receiver
from gateway.bus.wakeup import settle, woken_or_timeout
from gateway.errors import PortError

RECEIVE_CHUNK = 4096
URL_CHUNK = 256
PTY_SLAVE_MAJORS = range(136, 144)
"""Linux's device numbers for pseudo-terminal slaves (/dev/pts/N)."""
_PORT_ERRORS = (serial.SerialException, OSError, termios.error)


def is_pseudo_terminal(port: str) -> bool:
    """True for a pty (or a link to one): a virtual line, such as the simulator's."""
    try:
        device = os.stat(port).st_rdev  # follows links such as /dev/serial/by-id/...
    except (OSError, ValueError):
        return False  # not a path: a pyserial URL, or not there (open() will say so)
    return os.major(device) in PTY_SLAVE_MAJORS


def open_port(
    settings: LineSettings,
    receiver: Receiver,
    heard: Callable[[bytes], None],
    failed: Callable[[], None],
) -> Port:
    """Open the line's port and start listening to it; call with the event loop running.

    `heard`: given (in the reader callback) the bytes read, to keep in `receiver` (`Receiver.take`)
    unless they are a held caller's reply (`GapKeeper.heard`); `failed`: told that
    the port failed while nobody waited for it (an adapter unplugged between transactions).
    """
    loop = asyncio.get_running_loop()
    fmt = settings.char_format
    # A pty has no wire and no parity bit; Linux takes PARENB on one once and then refuses it
    # (EINVAL), so a virtual line that is opened again (a reopen, a field tool after a scan)
    # would fail. Timing still follows the configured format.
    virtual = is_pseudo_terminal(settings.port)
    try:
        raw = serial.serial_for_url(
            settings.port,
            baudrate=fmt.baudrate,
            parity="N" if virtual else fmt.parity,
            stopbits=fmt.stopbits,
            bytesize=fmt.bytesize,
            timeout=0,
            write_timeout=2.0,
            exclusive=True,
        )
    except (serial.SerialException, OSError, ValueError, termios.error) as exc:
        raise PortError(f"cannot open {settings.port}: {exc}") from exc
    try:
        _take_direction(raw, settings)
    except PortError:
        raw.close()
        raise
    # FTDI adapters hold received bytes up to 16 ms unless asked not to; not every port can.
    with contextlib.suppress(Exception):
        raw.set_low_latency_mode(True)
    try:
        fd: int | None = raw.fileno()
    except Exception:  # URL ports (socket://, loop://) have no descriptor to watch
        fd = None
    with contextlib.suppress(Exception):
        raw.reset_input_buffer()
    if fd is None:
        return UrlPort(raw, settings, receiver, loop, virtual)
    return TtyPort(raw, settings, receiver, loop, virtual, fd, heard, failed)


def _take_direction(raw: serial.SerialBase, settings: LineSettings) -> None:
    """Set the port up for the bus's RS-485 direction control, if any."""
    control = settings.direction
    if control is None:
        return
    if control.mode is DirectionMode.KERNEL:
        apply_kernel_mode(raw, control, settings.where)
    else:
        set_rts(raw, not control.rts_level_for_tx, settings.where)  # listening until a request


class Port(ABC):
    """An open serial port, as the line uses it; `TtyPort` or `UrlPort`."""

    watched = False
    """The loop watches the port: bytes are taken in as they come, with their arrival times."""
    readable_now: Callable[[int], list[tuple[int, int]]] | None = None
    """A watched port's `readable_now(0)`: non-empty when bytes are waiting (`bytes_waiting`
    as one C call, for the gap's end, which asks once or twice per transaction)."""
    fd = -1
    """A watched port's descriptor (the loop watches it); -1 for any other port."""

    def __init__(
        self,
        raw: serial.SerialBase,
        settings: LineSettings,
        receiver: Receiver,
        loop: asyncio.AbstractEventLoop,
        virtual: bool,
    ) -> None:
        self.raw = raw
        self.settings = settings
        self.receiver = receiver
        self.loop = loop
        self.virtual = virtual
        """A pty: no wire, so no wire timing to judge an echo by."""
        self.open = True
        self.usable = True
        """Open, and not failed."""
        self.error: PortError | None = None
        """Why the port failed, until the next use raises it (and closes the port)."""
        self.waiter: asyncio.Future[None] | None = None
        """Whoever waits for news from the port: bytes, or its failure."""
        self.silenced: str | None = None
        """Why no byte may go out any more (another master heard on the line: the redundant
        active's `WriteGate`): every write refuses, whoever asks; reading goes on."""

    def check(self) -> serial.SerialBase:
        """The port, if it is usable; else raise why not (closing it, if it failed)."""
        if self.error is not None:
            error = self.error
            self.close()
            self.error = None
            raise error
        if not self.open:
            raise PortError(f"{self.settings.port} is not open")
        return self.raw

    def close(self) -> None:
        self.usable = False
        if self.open:
            self.open = False
            with contextlib.suppress(Exception):
                self.raw.close()
        self.wake()

    def wake(self) -> None:
        waiter = self.waiter
        if waiter is not None and not waiter.done():
            waiter.set_result(None)

    def bytes_waiting(self) -> bool:
        """Bytes the kernel holds that the loop hasn't taken in yet (only a watched port knows)."""
        return False

    @abstractmethod
    def discard_pending(self) -> None:
        """Throw away bytes nobody asked for; a byte still arriving makes the line not quiet."""

    @abstractmethod
    async def wait(self, deadline: float) -> bool:
        """Wait for news: bytes came into the receiver (True), or `deadline` passed (False).
        Raises PortError when the port fails meanwhile."""

    @abstractmethod
    def write_now(self, frame: bytes) -> int:
        """Write what the port takes without waiting; how many bytes that was."""

    @abstractmethod
    async def write(self, frame: bytes) -> None:
        """Write all of `frame`."""

    def writable(self) -> serial.SerialBase:
        """`check`, for a write: also refused (PortError) once the port is silenced."""
        if self.silenced is not None:
            raise PortError(f"{self.settings.port}: nothing sent: {self.silenced}")
        return self.check()

    def write_whole(self, frame: bytes) -> None:
        """The whole frame through pyserial (RTS mode: the port's own write, then its drain)."""
        raw = self.writable()
        try:
            raw.write(frame)
        except _PORT_ERRORS as exc:
            raise self._failure("write to", exc) from exc

    async def drained(self, within_s: float) -> None:
        """Wait until the UART has sent its last bit (tcdrain blocks: a worker thread does it)."""
        raw = self.check()
        try:
            await asyncio.wait_for(self.loop.run_in_executor(None, raw.flush), within_s)
        except TimeoutError:
            self.close()
            raise PortError(
                f"{self.settings.port} doesn't finish sending (adapter wedged?)"
            ) from None
        except _PORT_ERRORS as exc:
            raise self._failure("drain of", exc) from exc

    def set_rts(self, level: bool) -> None:
        try:
            set_rts(self.check(), level, self.settings.where)
        except PortError:
            self.close()
            raise

    def _failure(self, what: str, exc: Exception) -> PortError:
        """Close the port that failed; the error to raise, naming it."""
        self.close()
        return PortError(f"{what} {self.settings.port} failed: {exc}")


class TtyPort(Port):
    """A serial device whose descriptor the event loop watches."""

    watched = True

    def __init__(
        self,
        raw: serial.SerialBase,
        settings: LineSettings,
        receiver: Receiver,
        loop: asyncio.AbstractEventLoop,
        virtual: bool,
        fd: int,
        heard: Callable[[bytes], None],
        failed: Callable[[], None],
    ) -> None:
        super().__init__(raw, settings, receiver, loop, virtual)
        self.fd = fd
        self._heard = heard
        self._failed = failed
        self._poll = select.poll()
        self._poll.register(fd, select.POLLIN)
        self.readable_now = self._poll.poll
        loop.add_reader(fd, self._readable)

    def close(self) -> None:
        if self.open and not self.loop.is_closed():
            self.loop.remove_reader(self.fd)
        super().close()

    def _readable(self) -> None:
        """The loop's reader callback: hand what arrived to the line, which keeps it."""
        try:
            data = os.read(self.fd, RECEIVE_CHUNK)
            # Called only when the loop saw the port readable, and nothing else reads it: a
            # serial port that is readable yet gives nothing has gone (pyserial reads it so too).
            if not data:
                raise OSError("device reports data but returns none (unplugged?)")
        except BlockingIOError:
            return
        except OSError as exc:
            self._fail(PortError(f"read from {self.settings.port} failed: {exc}"))
            return
        # A callable attribute: read, then called (a method call's lookup of it is
        # generic on Python 3.11, a plain read is specialised).
        heard = self._heard
        heard(data)

    def _fail(self, error: PortError) -> None:
        """The port is gone: stop watching it (a dead descriptor is readable forever)."""
        self.error = error
        self.usable = False
        self.loop.remove_reader(self.fd)
        if self.waiter is None:
            self._failed()
        self.wake()

    def bytes_waiting(self) -> bool:
        """Bytes the kernel holds that the loop hasn't taken in yet.

        The loop runs callbacks in the order they were queued: the bus (or the gap timer) may
        run before the reader callback for bytes that came in the same wake-up. They count:
        a frame must not go out less than t3.5 after them, nor they be taken for its reply.
        """
        return bool(self._poll.poll(0))

    def discard_pending(self) -> None:
        self.check()
        self.receiver.discard()
        if self._poll.poll(0):
            self.receiver.quiet_since = time.monotonic()  # not quiet: the gap starts again

    async def wait(self, deadline: float) -> bool:
        """Wait until the reader callback has news (bytes, or the port failed) or `deadline`
        passes (False at once if it has). Response and character timeouts need no
        sub-millisecond precision: call_later does."""
        self.check()  # failed while the caller was held: say so now, not at the timeout
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            return False
        waiter = self.waiter = self.loop.create_future()
        try:
            await woken_or_timeout(waiter, remaining)
        finally:
            if self.waiter is waiter:
                self.waiter = None
        self.check()
        return True

    def write_now(self, frame: bytes) -> int:
        if self.error is not None or not self.open or self.silenced is not None:
            self.writable()  # its call only when it raises
        try:
            return os.write(self.fd, frame)
        except BlockingIOError:  # the port's buffer is full: `write` waits for room
            return 0
        except _PORT_ERRORS as exc:
            raise self._failure("write to", exc) from exc

    async def write(self, frame: bytes) -> None:
        self.writable()
        view = memoryview(frame)
        # A frame takes its wire time to leave; an adapter that takes a second more is wedged,
        # and a bus stuck here would hold the line forever.
        deadline = time.monotonic() + self.settings.char_format.wire_time_s(len(frame)) + 1
        try:
            while view:
                try:
                    written = os.write(self.fd, view)
                except BlockingIOError:  # the port is non-blocking; its buffer is full
                    if not await self._writable(deadline):
                        raise OSError("the port takes no more bytes (adapter wedged?)") from None
                    continue
                view = view[written:]
        except _PORT_ERRORS as exc:
            raise self._failure("write to", exc) from exc

    async def _writable(self, deadline: float) -> bool:
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            return False
        waiter: asyncio.Future[None] = self.loop.create_future()
        self.loop.add_writer(self.fd, settle, waiter)
        try:
            await woken_or_timeout(waiter, remaining)
        finally:
            if self.open:
                self.loop.remove_writer(self.fd)
        return time.monotonic() < deadline


class UrlPort(Port):
    """A port named by a pyserial URL: read when the line waits, in the loop's thread pool."""

    def discard_pending(self) -> None:
        raw = self.check()
        receiver = self.receiver
        receiver.discard()
        try:
            raw.timeout = 0
            while data := raw.read(URL_CHUNK):
                receiver.discarded_bytes += len(data)
                receiver.quiet_since = time.monotonic()
        except (serial.SerialException, OSError) as exc:
            raise self._failure("read from", exc) from exc

    async def wait(self, deadline: float) -> bool:
        raw = self.check()

        def read() -> bytes:
            raw.timeout = max(deadline - time.monotonic(), 0.0)
            return bytes(raw.read(URL_CHUNK))

        try:
            data = await self.loop.run_in_executor(None, read)
        except (serial.SerialException, OSError) as exc:
            raise self._failure("read from", exc) from exc
        if not data:
            return False
        self.receiver.take(data)
        return True

    def write_now(self, frame: bytes) -> int:
        self.write_whole(frame)
        return len(frame)

    async def write(self, frame: bytes) -> None:
        self.write_whole(frame)
