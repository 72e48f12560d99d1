"""A simulated RS-485 line of INVT drives, served from a thread with blocking I/O.

Timing is the point of this class, so it runs on a thread with `select` and precise deadlines
rather than on an event loop shared with the code under test: a thread of its own, or one
`LineServer` thread serving several lines (a bench of many lines in one process).

A pty has no baud rate: bytes the gateway writes arrive at once. With `wire_time`, the line acts
as the wire would: a request of n bytes ends n character times after its first byte arrived; the
drive answers after its response delay (P14.03, at least t3.5), and the reply is written whole at
the moment its last character would have left the wire.

`stats["gap_violations"]` counts requests whose first byte came less than t3.5 after the end of
the previous frame on the line (a request, or a reply), or while a reply was going out: a master
that does that corrupts frames on a real line.

Two histograms say where a transaction's time goes besides the wire and the master
(`stats["reply_late_buckets"]`, `stats["heard_gap_buckets"]`, cumulative, in seconds): how late
each reply went out after the moment it was due (the drives' own lateness: this thread woken late
on a busy machine), and the silence beyond t3.5 the drives heard between a reply and the request
after it (the master's share, its reading of the reply and the relay between the pty ends: all
that the line waits for besides the drives; with `relay_s`, beyond the relay's two delays too,
which are the configured path's and not the master's: so its buckets, the same as the master's
excess gap's, resolve what is left rather than the relay's half-millisecond or so).
`stats["reply_late_s"]` is the replies' lateness summed: the time the line waited for drives
answering late, which no master could have used.

With `relay_s`, a relay sits between the master's port and the drives' wire, as a USB adapter's
timer or a serial device server does: every byte reaches the wire `relay_s` after the master
wrote it, and every reply reaches the master `relay_s` after it left the wire. Times the line
keeps (frames, gaps, the histograms) are the wire's, on the drives' side of the relay; only
when a reply is handed to the master is the master's.
"""

from __future__ import annotations

import contextlib
import heapq
import itertools
import logging
import os
import random
import threading
import time
from collections import deque
from collections.abc import Callable, Container, Iterable, Mapping, Sequence
from types import TracebackType
from typing import Any, Final

from gateway.buckets import Buckets
from gateway.bus.gap_excess import BOUNDS_S
from gateway.instruments.simulator.abb_drive import ABB_MODELS, SimulatedAbbDrive
from gateway.instruments.simulator.adapter import AdapterEffects
from gateway.instruments.simulator.drive import SimulatedDrive
from gateway.instruments.simulator.endpoint import Endpoint, point_link, remove_link
from gateway.instruments.simulator.framing import ReceivedFrame, RequestAssembler
from gateway.instruments.simulator.line_faults import LineFaults
from gateway.instruments.simulator.quirks import DeviceQuirks
from gateway.instruments.simulator.server import LineServer
from gateway.instruments.simulator.shared_wire import SharedWire
from gateway.modbus.functions import exception_pdu
from gateway.modbus.rtu import BROADCAST_ADDRESS, build_frame
from gateway.modbus.timing import CharacterFormat

log = logging.getLogger(__name__)

CALL_TIMEOUT_S: Final = 5.0
READ_SIZE: Final = 4096
# How long before a reply is due the line wakes and spins out the rest: a timer wake-up is late
# by up to a few hundred microseconds on a quiet machine. Several simulated lines on one
# machine should share it (`bench` gives each of N lines WAKE_EARLY_S / N): sixteen lines
# spinning 300 us before every reply took most of a core from the gateway they measured, and
# lines served from one thread wait while it spins for another's reply.
WAKE_EARLY_S: Final = 0.0003


class SimulatedLine:
    def __init__(
        self,
        addresses: Iterable[int] = (1,),
        model: str = "gd350",
        baudrate: int = 19200,
        parity: str = "E",
        stopbits: int = 1,
        wire_time: bool = True,
        response_delay_ms: float = 5.0,
        device: str | None = None,
        link: str | None = None,
        *,
        models: Mapping[int, str] | None = None,
        fault_history: Mapping[int, Sequence[int]] | None = None,
        wake_early_s: float = WAKE_EARLY_S,
        relay_s: float = 0.0,
        masters: int = 1,
    ) -> None:
        if relay_s < 0:
            raise ValueError(f"relay delay {relay_s * 1000:g} ms is negative")
        models = models or {}
        histories = fault_history or {}
        addresses = list(addresses)
        self.drives: dict[int, SimulatedDrive] = {
            address: SimulatedDrive(
                address, models.get(address, model), fault_history=histories.get(address, ())
            )
            for address in addresses
            if models.get(address, model) not in ABB_MODELS
        }
        """The INVT drives on the line."""
        self.abb_drives: dict[int, SimulatedAbbDrive] = {
            address: SimulatedAbbDrive(address, models.get(address, model))
            for address in addresses
            if models.get(address, model) in ABB_MODELS
        }
        """The ABB drives on the line (ABB Drives profile)."""
        self.model = model
        self.baudrate = baudrate
        self.parity = parity.upper()
        self.stopbits = stopbits
        self.wire_time = wire_time
        self.response_delay_ms = response_delay_ms
        self.device = device
        self.link = link
        self.wake_early_s = wake_early_s
        self.relay_s = relay_s
        """The relay's delay each way between the master's port and the wire."""
        char_format = CharacterFormat(baudrate, self.parity, stopbits)
        self.character_s = char_format.char_time_s
        self.t35_s = char_format.t35_s

        self._lock = threading.Lock()
        self._dead: set[int] = set()
        self._extra_delay_s: dict[int, tuple[float, float]] = {}
        """Address → how much later than its response delay it answers: drawn from this range
        for each reply (`set_reply_delay`)."""
        self._slow_random = random.Random(0)
        self._slow_share: dict[int, float] = {}
        """Address → the share of its replies that take the extra delay (`set_reply_delay`)."""
        self._quirks = DeviceQuirks()
        self._faults = LineFaults()
        self._adapter = AdapterEffects()
        self._wire = None if masters == 1 else SharedWire(masters, self.t35_s)
        """With several masters (`gateway.instruments.simulator.shared_wire`): their ports,
        what each transmitted, and the collisions."""
        self._stats: dict[str, Any] = {
            "requests": 0,
            "replies": 0,
            "broadcasts": 0,
            "crc_errors": 0,
            "ignored": 0,
            "gap_violations": 0,
            "min_gap_s": None,
            "faults_injected": 0,
            "faults_by_kind": {},
        }

        self._endpoint: Endpoint | None = None
        self._path: str | None = None
        self._server: LineServer | None = None
        self._thread: threading.Thread | None = None
        """The thread serving the line, set by its `LineServer` once it runs."""
        self._stopping = False
        self._wake_read = self._wake_write = -1
        self._calls: deque[_Call] = deque()
        self._assembler = RequestAssembler(self.t35_s)
        # (due, sequence, bytes, ends a reply): a heap, due when the master gets the bytes (the
        # relay's delay after they left the wire). A reply delivered in bursts is several.
        self._pending: list[tuple[float, int, bytes, bool]] = []
        self._sequence = itertools.count()
        self._answered_by: dict[int, float] = {}
        self._last_reply_due = 0.0
        """When the last reply scheduled to cross the wire after all others ends."""
        self._delivered_by = 0.0
        """When the adapter hands over the last part of that reply (bursts hold parts back)."""
        """Address → when its last scheduled reply ends: a drive answers in order, so a reply
        to a later request never overtakes a late one (a busy drive, not a reordering line)."""
        self._last_frame_end: float | None = None
        self._request_wire_end = 0.0
        self._reply_late = Buckets(BOUNDS_S)
        self._heard_gap = Buckets(BOUNDS_S)
        self._reply_ended_at: float | None = None
        """When the last reply went out, until the request after it comes."""

    # ----------------------------------------------------------------- lifecycle

    def start(self) -> None:
        """Open the pty (or the device), point `link` at it, start serving from a thread of
        its own (`LineServer` serves several lines from one)."""
        if self._server is not None:
            raise RuntimeError("the simulated line is already started")
        LineServer([self]).start()

    def stop(self) -> None:
        """Stop serving (promptly), close the port, remove the link. Safe to call twice. A line
        served with others from one thread stops them too: they share the thread."""
        server = self._server
        if server is not None:
            server.stop()

    # ----------------------------------------------------------------- as `LineServer` serves it
    # (`gateway.instruments.simulator.server.ServedLine`)

    def open_for(self, server: LineServer) -> None:
        """Before `server`'s thread serves this line: the wake-up pipe and the port."""
        self._wake_read, self._wake_write = os.pipe()
        try:
            self._plug()
        except BaseException:
            self._close_wake_pipe()
            raise
        self._stopping = False
        self._server = server

    def served_from(self, thread: threading.Thread) -> None:
        """The thread that serves the line from now on: control calls run there."""
        self._thread = thread

    def stop_serving(self) -> None:
        """The serving thread stops: the pass under way ends at once, and the thread wakes."""
        self._stopping = True
        self._wake()

    def close_port(self) -> None:
        """After `server`'s thread stopped: the port and the wake-up pipe closed."""
        self._thread = self._server = None
        self._unplug()
        self._close_wake_pipe()

    def _close_wake_pipe(self) -> None:
        for fd in (self._wake_read, self._wake_write):
            with contextlib.suppress(OSError):
                os.close(fd)
        self._wake_read = self._wake_write = -1

    def __enter__(self) -> SimulatedLine:
        if self._server is None:
            self.start()
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        error: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.stop()

    @property
    def path(self) -> str:
        """What the gateway opens: the link if one was asked for, else the pty or the device."""
        if self.link is not None:
            return self.link
        if self._path is None:
            raise RuntimeError("the simulated line has no port yet: call start()")
        return self._path

    @property
    def paths(self) -> list[str]:
        """Every master's port: one, or each of `masters` on a shared wire."""
        return [self.path] if self._wire is None else self._wire.paths

    # ----------------------------------------------------------------- controls

    def set_dead(self, address: int, dead: bool = True) -> None:
        """A dead address never answers."""
        with self._lock:
            self._drive(address)
            (self._dead.add if dead else self._dead.discard)(address)

    def inject_fault(self, address: int, code: int) -> None:
        """The drive trips with `code` (an ABB drive's status word shows TRIPPED)."""
        with self._lock:
            self._any_drive(address).inject_fault(code, time.monotonic())

    def clear_fault(self, address: int) -> None:
        with self._lock:
            self._any_drive(address).clear_fault(time.monotonic())

    def set_output_current(self, address: int, amps: float | None, jitter_a: float = 0.0) -> None:
        """One drive's output current (3004H), jittering by up to ±`jitter_a` per read."""
        with self._lock:
            self._drive(address).set_output_current(amps, jitter_a)

    def set_fault_history(self, address: int, codes: Sequence[int]) -> None:
        """P07.27-P07.32 of one drive, newest first."""
        with self._lock:
            self._drive(address).set_fault_history(codes)

    def set_reply_delay(
        self, address: int, ms: float, up_to_ms: float | None = None, share: float = 1.0
    ) -> None:
        """This address answers `ms` later than its response delay (or, with `up_to_ms`, a
        delay drawn at random from that range for each reply, as a drive busy writing its
        EEPROM does); 0 makes it punctual again. `share`: only that share of its replies,
        at random, are late (the rest come after the response delay)."""
        low = max(ms, 0.0) / 1000
        high = low if up_to_ms is None else max(up_to_ms / 1000, low)
        with self._lock:
            self._drive(address)
            self._extra_delay_s[address] = (low, high)
            self._slow_share[address] = share

    def know_only(self, address: int, functions: Iterable[int] | None) -> None:
        """This address frames only `functions` and stays silent to any other (a libmodbus
        device: no exception 01H); None: every function its drive has
        (`gateway.instruments.simulator.quirks`)."""
        with self._lock:
            self._any_drive(address)
            self._quirks.know_only(address, functions)

    def refuse(self, address: int, code: int | None) -> None:
        """This address answers every request with exception `code` (a standard device
        busy: 06H); None: it answers again (`gateway.instruments.simulator.quirks`)."""
        with self._lock:
            self._any_drive(address)
            self._quirks.refuse(address, code)

    def stall(self, address: int, seconds: float) -> None:
        """This address stalls for `seconds` from now: it answers what it takes meanwhile
        once it carries on, in order."""
        with self._lock:
            self._any_drive(address)
            self._quirks.stall(address, time.monotonic() + seconds)

    def drop_requests(self, address: int, rate: float) -> None:
        """This address never answers `rate` of its requests, at random."""
        with self._lock:
            self._any_drive(address)
            self._quirks.drop(address, rate)

    def set_line_faults(
        self,
        rate: float = 0.05,
        kinds: Iterable[str] | None = None,
        seed: int | None = None,
        late_ms: float = 500.0,
        late_from_ms: float | None = None,
    ) -> None:
        """Spoil each reply with probability `rate`, one of `kinds` (all when None) at random;
        a late reply comes `late_ms` late, or at random from `late_from_ms` to `late_ms`."""
        late_from_s = None if late_from_ms is None else late_from_ms / 1000
        with self._lock:
            self._faults.configure(rate, kinds, seed, late_ms / 1000, late_from_s)

    def set_adapter(
        self, *, burst_ms: float = 0.0, glitch: bytes = b"", echo: bool = False
    ) -> AdapterEffects:
        """How the gateway's adapter hands over what it receives: in bursts every `burst_ms`
        (each reply cut in the middle), with a `glitch` byte before each reply, echoing each
        request. All off by default."""
        if burst_ms < 0:
            raise ValueError(f"burst period {burst_ms} ms is negative")
        if len(glitch) > 1:
            raise ValueError("a glitch is one byte, e.g. 00 or FF")
        effects = AdapterEffects(burst_ms / 1000, bytes(glitch), echo)
        with self._lock:
            self._adapter = effects
        return effects

    @property
    def adapter(self) -> AdapterEffects:
        return self._adapter

    def write_raw(self, data: bytes) -> None:
        """Put arbitrary bytes (noise) on the line now."""
        self._in_loop(lambda: self._write(data))

    def unplug(self) -> None:
        """Close the port: the gateway's open port fails as if the USB adapter were pulled."""
        self._in_loop(self._unplug)

    def unplug_master(self, master: int) -> None:
        """With `masters`: that master's port (from 1) goes away as if its USB adapter were
        pulled; the others stay on the line."""
        wire = self._wire
        if wire is None:
            raise ValueError("unplug-master needs a line shared by several masters")
        self._in_loop(lambda: wire.unplug(master - 1))

    def replug(self) -> None:
        """A new pty (a new name, like a re-enumerated adapter); `link` points at it again."""
        self._in_loop(self._plug)

    @property
    def stats(self) -> dict[str, Any]:
        """A snapshot: requests, replies, broadcasts, crc_errors, ignored, gap_violations,
        min_gap_s, faults_injected (spoilt replies), faults_by_kind, the histograms
        reply_late_buckets and heard_gap_buckets and the sum reply_late_s (see the module's
        docstring)."""
        with self._lock:
            shared = {} if self._wire is None else self._wire.stats()
            return {
                **self._stats,
                **shared,
                "faults_by_kind": dict(self._stats["faults_by_kind"]),
                "reply_late_buckets": self._reply_late.cumulative(),
                "reply_late_s": self._reply_late.sum_s,
                "heard_gap_buckets": self._heard_gap.cumulative(),
            }

    @property
    def writes(self) -> list[tuple[int, int, int, int]]:
        """With `masters`: every 06H write the drives got whole, in order, as (master from 1,
        unit, register, value); none on a line of one master."""
        with self._lock:
            return [] if self._wire is None else list(self._wire.writes)

    @property
    def lock(self) -> threading.Lock:
        """Hold it to look at `drives` while the line is serving."""
        return self._lock

    def _any_drive(self, address: int) -> SimulatedDrive | SimulatedAbbDrive:
        """An INVT or an ABB drive: for what both simulate (a fault)."""
        abb = self.abb_drives.get(address)
        return abb if abb is not None else self._drive(address)

    def _drive(self, address: int) -> SimulatedDrive:
        try:
            return self.drives[address]
        except KeyError:
            raise ValueError(
                f"no simulated drive at address {address}: the line has {sorted(self.drives)}"
            ) from None

    # ----------------------------------------------------------------- the thread

    @property
    def endpoint(self) -> Endpoint | None:
        """The port the thread reads; another one after a replug (None while unplugged)."""
        return self._endpoint

    def watched(self) -> list[int]:
        """The descriptors the serving thread waits on for this line."""
        endpoint = self._endpoint
        if endpoint is None:
            return [self._wake_read]
        return [self._wake_read, *([endpoint.fd] if self._wire is None else self._wire.fds())]

    def serve_ready(self, readable: Container[int], woke_at: float) -> None:
        """One pass of the serving thread for this line: `readable` are the descriptors its
        wait found ready (this line's among others) when it woke at `woke_at`."""
        if self._wake_read in readable:
            os.read(self._wake_read, READ_SIZE)
        if self._stopping:
            return
        endpoint = self._endpoint
        self._run_calls()
        self._send_due(time.monotonic())
        wire = self._wire
        if wire is not None:
            if endpoint is not None and endpoint is self._endpoint:
                for fd in wire.fds():
                    if fd in readable:
                        self._receive_shared(wire, fd, woke_at)
            self._release_shared(wire)
        elif endpoint is not None and endpoint is self._endpoint and endpoint.fd in readable:
            # The bytes were there when the wait ended: their time, however many lines' work
            # came before this one's in the pass (a master's request is not later for that).
            self._receive(endpoint, woke_at)
        with self._lock:
            for frame in self._assembler.on_silence(time.monotonic() + self.relay_s):
                self._on_frame(frame)

    def deadline(self) -> float | None:
        """When the serving thread must next serve this line with nothing to read: a little
        before a reply is due (`_send_due` waits out the rest: a timer wake-up is late by up
        to a few hundred microseconds, and a drive that answers late would make the gateway
        look slower than the line allows), or when the silence that ends a request is over."""
        deadline = self._pending[0][0] - self.wake_early_s if self._pending else None
        silence = self._assembler.silence_deadline()
        wire = self._wire
        if wire is not None:
            for shared in (wire.silence_deadline(), wire.next_due()):
                if shared is not None:
                    silence = shared if silence is None else min(silence, shared)
        if silence is not None:
            silence -= self.relay_s  # the wire's time, the relay's delay ahead
            deadline = silence if deadline is None else min(deadline, silence)
        return deadline

    def _receive(self, endpoint: Endpoint, now: float) -> None:
        try:
            data = os.read(endpoint.fd, READ_SIZE)
        except BlockingIOError:
            return
        except OSError as error:
            log.warning("simulated line: %s vanished (%s)", endpoint.path, error)
            self._unplug()
            return
        if not data:
            log.warning("simulated line: %s closed", endpoint.path)
            self._unplug()
            return
        with self._lock:
            # The bytes reach the drives' wire the relay's delay after the master wrote them.
            for frame in self._assembler.feed(data, now + self.relay_s):
                self._on_frame(frame)
            if self._adapter.echo:
                self._echo(data, now)

    def _receive_shared(self, wire: SharedWire, fd: int, now: float) -> None:
        """Bytes from one of several masters: every other master hears them at once, and they
        go on the wire, where they may collide (`SharedWire.transmit`)."""
        master = wire.master_of(fd)
        if master is None:
            return
        try:
            data = os.read(fd, READ_SIZE)
        except BlockingIOError:
            return
        except OSError as error:
            log.warning("simulated line: master %d's port vanished (%s)", master + 1, error)
            return
        if not data:
            return
        wire.relay(master, data)
        with self._lock:
            for frame in wire.feed(master, data, now + self.relay_s):
                self._on_air(wire, master, frame)

    def _release_shared(self, wire: SharedWire) -> None:
        """Frames whose end has left the wire go to the drives (a garbled one fails its CRC);
        frames that a silence ends go on the wire first."""
        with self._lock:
            for master, frame in wire.on_silence(time.monotonic() + self.relay_s):
                self._on_air(wire, master, frame)
            for frame in wire.released(time.monotonic() + self.relay_s):
                self._on_frame(frame)

    def _on_air(self, wire: SharedWire, master: int, frame: ReceivedFrame) -> None:
        """`master`'s frame is on the wire: a reply going out meanwhile is garbled with it."""
        character_s = self.character_s if self.wire_time else 0.0
        replies = [
            (at - self.relay_s - len(data) * character_s, at - self.relay_s)
            for at, _, data, _ in self._pending
        ]
        sent = wire.transmit(master, frame, character_s, replies)
        if sent.garbled:
            self._garble_replies(sent.start, sent.end, character_s)

    def _garble_replies(self, start: float, end: float, character_s: float) -> None:
        """Replies on the wire between `start` and `end` reach the masters with a bad CRC."""
        garbled = []
        for at, sequence, data, ends in self._pending:
            wire_end = at - self.relay_s
            if wire_end - len(data) * character_s < end and start < wire_end and data:
                data = data[:-1] + bytes([data[-1] ^ 0xFF])
            garbled.append((at, sequence, data, ends))
        heapq.heapify(garbled)
        self._pending = garbled

    def _echo(self, data: bytes, now: float) -> None:
        """The adapter hands the master's bytes back as they leave on the wire: each byte a
        character time after the one before (at once without wire time), so a master reads
        the echo in pieces, as it does from real 2-wire adapters."""
        if not self.wire_time:
            self._write(data)
            return
        for index in range(len(data)):
            at = now + (index + 1) * self.character_s
            heapq.heappush(
                self._pending, (at, next(self._sequence), data[index : index + 1], False)
            )

    def _on_frame(self, frame: ReceivedFrame) -> None:
        """A request: count it, check the gap before it, hand it to its drive."""
        if not frame.valid:
            self._stats["crc_errors"] += 1
            return
        self._stats["requests"] += 1
        if self._reply_ended_at is not None:  # the master's turn after a reply
            heard = frame.first_byte_at - self._reply_ended_at
            self._heard_gap.observe(heard - self.t35_s - 2 * self.relay_s)
            self._reply_ended_at = None
        character_s = self.character_s if self.wire_time else 0.0
        request_wire_s = len(frame.data) * character_s
        self._check_gap(frame.first_byte_at, request_wire_s, character_s)
        # The UART sends one frame after another: a request can't start before the last ended.
        wire_start = max(frame.first_byte_at, self._request_wire_end)
        wire_end = max(wire_start + request_wire_s, frame.last_byte_at)
        self._request_wire_end = wire_end
        self._frame_ended(wire_end)
        address, pdu = frame.data[0], frame.data[1:-2]
        if address == BROADCAST_ADDRESS:
            self._stats["broadcasts"] += 1
            for each in self.drives.values():
                each.apply_broadcast(pdu, wire_end)
            for abb in self.abb_drives.values():
                abb.apply_broadcast(pdu, wire_end)
            return
        drive: SimulatedDrive | SimulatedAbbDrive | None = self.drives.get(address)
        drive = drive or self.abb_drives.get(address)
        if (
            drive is None
            or address in self._dead
            or self._quirks.silent(address, pdu[0] if pdu else 0)
        ):
            self._stats["ignored"] += 1
            return
        refusal = self._quirks.refusal(address)
        function = pdu[0] if pdu else 0
        answer = (
            drive.handle(pdu, wire_end) if refusal is None else exception_pdu(function, refusal)
        )
        reply = build_frame(address, answer)
        delay_s = self._response_delay_s(drive) + self._extra_delay(address)
        # A stalled device takes the request in and answers once it carries on.
        delay_s = max(delay_s, self._quirks.answers_from(address) - wire_end)
        spoilt = self._faults.maybe_spoil(reply)
        if spoilt is not None:
            self._stats["faults_injected"] += 1
            by_kind = self._stats["faults_by_kind"]
            by_kind[spoilt.kind] = by_kind.get(spoilt.kind, 0) + 1
            if spoilt.frame is None:
                return
            reply, delay_s = spoilt.frame, delay_s + spoilt.extra_delay_s
        due = wire_end + delay_s + len(reply) * character_s
        due = max(due, self._answered_by.get(address, 0.0) + len(reply) * character_s)
        self._answered_by[address] = due
        # The master gets it the relay's delay after it left the wire.
        parts = self._adapter.deliveries(reply, due + self.relay_s, character_s)
        # The adapter hands bytes over in the order they crossed the wire: a reply right behind
        # one whose last part is held back for a burst comes after that part, never into it.
        in_order = due >= self._last_reply_due
        if in_order:
            self._last_reply_due = due
        for index, (at, part) in enumerate(parts, 1):
            if in_order:
                at = self._delivered_by = max(at, self._delivered_by)
            heapq.heappush(self._pending, (at, next(self._sequence), part, index == len(parts)))

    def _extra_delay(self, address: int) -> float:
        low, high = self._extra_delay_s.get(address, (0.0, 0.0))
        share = self._slow_share.get(address, 1.0)
        if share < 1.0 and self._slow_random.random() >= share:
            return 0.0
        return low if low == high else self._slow_random.uniform(low, high)

    def _response_delay_s(self, drive: SimulatedDrive | SimulatedAbbDrive) -> float:
        """P14.03 once written over Modbus, else the line's `response_delay_ms`; at least t3.5
        when emulating the wire (a drive can't answer inside the gap that ends the request)."""
        written = "P14.03" in drive.written_parameters
        delay_s = (drive.response_delay_ms if written else self.response_delay_ms) / 1000
        return max(delay_s, self.t35_s) if self.wire_time else delay_s

    def _check_gap(self, first_byte_at: float, request_wire_s: float, character_s: float) -> None:
        gaps = []
        if self._last_frame_end is not None:
            gaps.append(first_byte_at - self._last_frame_end)
        for handed_over, _, reply, _ in self._pending:
            due = handed_over - self.relay_s  # when it leaves the wire
            reply_starts = due - len(reply) * character_s
            if first_byte_at + request_wire_s + self.t35_s > reply_starts:
                gaps.append(first_byte_at - due)  # collides with a reply still to go out
        if not gaps:
            return
        gap = min(gaps)
        if gap < self.t35_s:
            self._stats["gap_violations"] += 1
        smallest = self._stats["min_gap_s"]
        self._stats["min_gap_s"] = gap if smallest is None else min(smallest, gap)

    def _frame_ended(self, at: float) -> None:
        if self._last_frame_end is None or at > self._last_frame_end:
            self._last_frame_end = at

    def _send_due(self, now: float) -> None:
        if self._pending and self._pending[0][0] - now <= self.wake_early_s:
            due = self._pending[0][0]
            while time.monotonic() < due:  # spins at most wake_early_s, in the simulator only
                pass
            now = time.monotonic()
        while self._pending and self._pending[0][0] <= now:
            due, _, reply, ends_reply = heapq.heappop(self._pending)
            written_at = time.monotonic()
            # Counted before the master can ask: whoever reads `stats` once it has the reply
            # waits for the lock, held from the write until the reply is counted.
            with self._lock:
                if not (self._write(reply) and ends_reply):
                    continue
                left_wire_at = written_at - self.relay_s  # the relay held it this long
                self._stats["replies"] += 1
                self._frame_ended(left_wire_at)
                self._reply_late.observe(written_at - due)
                self._reply_ended_at = left_wire_at

    def _write(self, data: bytes) -> bool:
        endpoint = self._endpoint
        if endpoint is None:
            return False
        if self._wire is not None:
            return self._wire.write_all(data)  # every master hears the drives
        try:
            os.write(endpoint.fd, data)
        except BlockingIOError:
            log.warning("simulated line: %s is full, %d bytes dropped", endpoint.path, len(data))
            return False
        except OSError as error:
            log.warning("simulated line: write to %s failed (%s)", endpoint.path, error)
            return False
        return True

    # ----------------------------------------------------------------- port and calls

    def _plug(self) -> None:
        if self._endpoint is not None:
            return
        if self._wire is not None:
            endpoint = self._wire.open()[0]
        elif self.device is None:
            endpoint = Endpoint.open_pty()
        else:
            endpoint = Endpoint.open_device(self.device, self.baudrate, self.parity, self.stopbits)
        self._endpoint, self._path = endpoint, endpoint.path
        if self.link is not None:
            point_link(self.link, endpoint.path)

    def _unplug(self) -> None:
        endpoint, self._endpoint = self._endpoint, None
        if self._wire is not None:
            self._wire.close()
        elif endpoint is not None:
            endpoint.close()
        if self.link is not None:
            remove_link(self.link)
        self._pending.clear()
        self._answered_by.clear()
        self._last_reply_due = self._delivered_by = 0.0
        with self._lock:
            self._assembler = RequestAssembler(self.t35_s)
            self._reply_ended_at = None  # the time unplugged is nobody's silence on the line

    def _in_loop(self, action: Callable[[], object]) -> None:
        """Run `action` on the line's thread (it owns the port), and wait for it."""
        thread = self._thread
        if thread is None or thread is threading.current_thread():
            action()
            return
        call = _Call(action)
        self._calls.append(call)
        self._wake()
        if not call.done.wait(CALL_TIMEOUT_S):
            raise TimeoutError("the simulated line did not respond")
        if call.error is not None:
            raise call.error

    def _run_calls(self) -> None:
        while self._calls:
            call = self._calls.popleft()
            try:
                call.action()
            except Exception as error:  # handed back to the caller, raised there
                call.error = error
            call.done.set()

    def _wake(self) -> None:
        with contextlib.suppress(OSError):
            os.write(self._wake_write, b"\0")


class _Call:
    def __init__(self, action: Callable[[], object]) -> None:
        self.action = action
        self.done = threading.Event()
        self.error: Exception | None = None
