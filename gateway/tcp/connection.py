"""One Modbus-TCP client's connection: MBAP frames parsed out of what arrives, each request
answered as soon as it is ready, with its own transaction id, in any order; a read that is one
bus transaction answered by the bus itself (`_Answer`, a waiter, no task). What the connection
asks of its server is `Front` (`gateway.tcp.server.ModbusTcpServer`)."""

from __future__ import annotations

import asyncio
import logging
from typing import Protocol, cast

from gateway.bus.queue import Waiter
from gateway.errors import ExceptionCode, MalformedFrame
from gateway.logs import repeated
from gateway.modbus.functions import exception_pdu, front_door, lookup
from gateway.modbus.mbap import (
    COUNTED_FROM,
    HEADER_LENGTH,
    MAX_FRAME,
    MIN_FRAME,
    build_adu,
    frame_header,
    read_header,
)
from gateway.tcp.access import AccessPolicy
from gateway.tcp.cert_roles import client_role
from gateway.tcp.settings import TcpSettings
from gateway.tcp.stats import TcpStats

log = logging.getLogger("gateway.tcp.server")


class RequestRoute(Protocol):
    """Where the server sends what its clients ask (the gateway's router, with the SCADA write
    audit around it: `gateway.app`)."""

    async def execute(self, unit_id: int, pdu: bytes, client: str) -> bytes | None:
        """The reply PDU to `pdu` for `unit_id`, or None when nothing answers (a broadcast)."""
        ...

    def submit(self, unit_id: int, pdu: bytes, client: str, waiter: Waiter) -> bool:
        """Start a read that is one bus transaction without a task: True when `waiter` will
        get its reply (or error); False: it needs `execute`. Raises a ModbusError when it is
        refused before reaching a bus."""
        ...


class Front(Protocol):
    """What a connection asks of its server (`ModbusTcpServer`)."""

    settings: TcpSettings
    stats: TcpStats
    access: AccessPolicy | None
    route: RequestRoute
    _drained: asyncio.Future[None] | None

    def admit(self, connection: Connection) -> bool: ...

    def forget(self, connection: Connection) -> None: ...

    def refusal(self, unit_id: int, pdu: bytes, client: str, role: str | None) -> bytes | None: ...

    def error_reply(
        self, unit_id: int, function: int, client: str, exc: BaseException
    ) -> bytes: ...

    async def forward(self, unit_id: int, pdu: bytes, client: str) -> bytes | None: ...

    async def reply(
        self, unit_id: int, pdu: bytes, client: str, role: str | None = None
    ) -> bytes | None: ...

    def _settled(self) -> None: ...


# Once part of a frame has arrived, the rest follows at once; a client that stops halfway is
# broken, and waiting for it the whole idle timeout would hold a connection slot.
PARTIAL_FRAME_TIMEOUT_S = 5.0
FRAMES_PER_PASS = 32
"""Requests taken from one client in one pass of the event loop; the rest of what it sent waits
for the next pass (its socket not read meanwhile). A client that sends thousands at once (each
answered at once: an unknown unit id, a cached read) would otherwise hold the loop for tens of
milliseconds, and every other client and the line's gap timer with it. 32 of the cheapest
answers take a few milliseconds."""


class Connection(asyncio.Protocol):
    """One Modbus-TCP client: frames in, answers out, in whatever order they are ready."""

    def __init__(self, server: Front) -> None:
        self.server = server
        self.client = "tcp:?:0"
        self.host = "?"
        self.answers: set[asyncio.Task[None]] = set()
        self._reads: set[asyncio.Task[None]] = set()
        """Answers to pure reads: nobody will receive them once the client has gone."""
        self._taskless: set[_Answer] = set()
        """Reads answered by their waiter (`_Answer`, no task), waiting for the bus."""
        self._transport: asyncio.Transport | None = None
        self.gone = True
        """No answer can reach the client: not connected yet, closed or aborted here, or lost.
        An attribute, not the transport's `is_closing()`: a taskless read asks it twice
        (`_Answer.done`), and asyncio's transport answers in Python. A transport the loop
        closes itself (the client's EOF, an error) is `gone` a pass later, at `connection_lost`."""
        self._buffer = bytearray()
        self._paused = False
        self._deferred = False
        """Frames are left in the buffer for the next pass of the loop (`FRAMES_PER_PASS`):
        reading the socket waits for them."""
        self._write_blocked = False
        self._loop = asyncio.get_running_loop()
        self._last_data = self.connected_at = self._loop.time()
        self._frame_started = 0.0
        """When the first byte of the frame now in the buffer arrived."""
        self.served = False
        """A request of this connection has been completed (parsed whole)."""
        self._writes_waiting = 0
        self._idle_timer: asyncio.TimerHandle | None = None
        self._idle_due = float("inf")
        self.role: str | None = None
        """A TLS client's role, from its certificate; None on the plain listener."""
        self.tls = False
        self.requests = 0
        self.errors = 0
        """Requests of this connection answered with an exception (for diagnostics)."""

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        # A stream transport: asyncio's, or uvloop's (which doesn't derive from asyncio's
        # classes, so no isinstance check here).
        self._transport = cast(asyncio.Transport, transport)
        self.gone = False
        peer = transport.get_extra_info("peername") or ("?", 0)
        self.host = str(peer[0])
        self.client = f"tcp:{peer[0]}:{peer[1]}"
        secure = transport.get_extra_info("ssl_object")
        self.tls = secure is not None
        if secure is not None and self.server.settings.tls is not None:
            # The handshake is done: the certificate is one the configured CA signed.
            role_map = self.server.settings.tls.role_map
            self.role = client_role(
                secure.getpeercert(binary_form=True), secure.getpeercert(), role_map
            )
            log.debug("%s: TLS client, role %s", self.client, self.role or "(none)")
        if not self.server.admit(self):
            self.close()
            return
        self._arm_idle_timer()

    def connection_lost(self, exc: Exception | None) -> None:
        self.gone = True
        self.server.forget(self)
        if self._idle_timer is not None:
            self._idle_timer.cancel()
        # A read nobody will receive must not cost bus time: cancelling its answer takes it out
        # of the queue (a read shared with other clients still goes out for them). Writes go on:
        # the client sent them, and a half-done split write is worse than a finished one.
        for read in self._reads:
            read.cancel()
        # A taskless read is no longer wanted once its connection is gone (`_Answer.done`).
        self._taskless.clear()
        self.server._settled()

    def close(self) -> None:
        self.gone = True
        if self._transport is not None:
            self._transport.close()

    def abort(self) -> None:
        self.gone = True
        if self._transport is not None:
            self._transport.abort()

    @property
    def closing(self) -> bool:
        return self._transport is None or self._transport.is_closing()

    @property
    def in_flight(self) -> int:
        """Requests taken and not yet answered."""
        return len(self.answers) + len(self._taskless)

    @property
    def settling(self) -> bool:
        """Taskless reads' answers are still on their way."""
        return bool(self._taskless)

    def data_received(self, data: bytes) -> None:
        now = self._last_data = self._loop.time()
        if not self._buffer:
            size = len(data)
            if MIN_FRAME <= size <= MAX_FRAME and not self._paused:
                # The common case: a client that waits for each answer sends each request in
                # one segment, so the chunk is one whole frame with nothing before it. Its
                # header is read from the chunk itself, without the buffer; anything else (a
                # bad header, a part of a frame, several frames) goes the buffer's way below. A
                # size within MIN_FRAME..MAX_FRAME that matches the length field is a length
                # within MIN_LENGTH..MAX_LENGTH: `frame_header`'s checks, all passed.
                transaction_id, protocol_id, length, unit_id = read_header(data)
                if length == size - COUNTED_FROM and not protocol_id:
                    self._take_frame(transaction_id, unit_id, data[HEADER_LENGTH:])
                    return
            self._frame_started = now
        self._buffer += data
        self._take_frames()
        if self._buffer and not self.in_flight:
            # A frame has begun and stays incomplete: its own deadline may be the nearest now.
            limit = min(PARTIAL_FRAME_TIMEOUT_S, self.server.settings.idle_timeout_s)
            if self._frame_started + limit < self._idle_due:
                self._rearm_idle_timer()

    def _take_frames(self) -> None:
        buffer = self._buffer
        budget = FRAMES_PER_PASS
        while len(buffer) >= HEADER_LENGTH and not self._paused:
            if not budget:
                self._defer_frames()
                return
            budget -= 1
            try:
                transaction_id, unit_id, pdu_length = frame_header(buffer)
            except MalformedFrame as exc:
                self.server.stats.malformed += 1
                log.warning(
                    "%s closed: malformed frame (%s)",
                    self.client,
                    exc,
                    extra=repeated("tcp-malformed"),
                )
                self.close()
                buffer.clear()
                return
            end = HEADER_LENGTH + pdu_length
            if len(buffer) < end:
                return
            pdu = bytes(buffer[HEADER_LENGTH:end])
            del buffer[:end]
            if buffer:
                self._frame_started = self._last_data  # the next frame began in the last chunk
            self._take_frame(transaction_id, unit_id, pdu)

    def _take_frame(self, transaction_id: int, unit_id: int, pdu: bytes) -> None:
        """One whole request: a write takes a task; a read goes to its bus in this pass of the
        event loop, answered by the bus itself (an `_Answer`, no task), unless it needs
        `RequestRoute.execute` (the router says so)."""
        self.served = True
        server = self.server
        server.stats.requests += 1
        self.requests += 1
        reads_only, malformed = front_door(pdu)
        if not reads_only:  # a write
            if self._writes_waiting >= server.settings.max_queued_writes_per_client:
                self._refuse_write(transaction_id, unit_id, pdu)
                return
            self._writes_waiting += 1
            self._start_task(transaction_id, unit_id, pdu, True, False)
            return
        # The front door first (`refusal`), which a well-formed read passes without a call when
        # there are no access rules: `read_only` refuses writes only.
        if malformed is not None or server.access is not None:
            refusal = server.refusal(unit_id, pdu, self.client, self.role)
            if refusal is not None:
                self._send(transaction_id, unit_id, refusal)
                return
        answer = _Answer(self, transaction_id, unit_id, pdu[0])
        try:
            if not server.route.submit(unit_id, pdu, self.client, answer):
                # The front door has let it pass: the handler's way, in a task.
                self._start_task(transaction_id, unit_id, pdu, False, True)
                return
        except Exception as exc:  # refused before the bus: answered at once
            self._send(
                transaction_id, unit_id, server.error_reply(unit_id, pdu[0], self.client, exc)
            )
            return
        if not answer.settled:  # not answered from the cache at once: the bus has it
            taskless = self._taskless
            taskless.add(answer)
            if len(self.answers) + len(taskless) >= server.settings.max_requests_per_connection:
                # Back-pressure: stop reading this client until an answer has gone out.
                self._pause()

    def _defer_frames(self) -> None:
        """The pass's budget is spent: take the rest in the next pass, reading nothing more
        from the socket until then (the kernel holds it, and TCP slows the client down)."""
        if self._deferred:
            return
        self._deferred = True
        transport = self._transport
        if transport is not None and not transport.is_closing() and not self._paused:
            transport.pause_reading()
        self._loop.call_soon(self._take_deferred)

    def _take_deferred(self) -> None:
        self._deferred = False
        transport = self._transport
        if transport is None or transport.is_closing():
            return
        self._take_frames()
        if not self._deferred and not self._paused:
            transport.resume_reading()

    def _start_task(
        self, transaction_id: int, unit_id: int, pdu: bytes, write: bool, checked: bool
    ) -> None:
        answer = self._loop.create_task(self._answer(transaction_id, unit_id, pdu, write, checked))
        self.answers.add(answer)
        if lookup(pdu[0]).coalescable:  # a pure read
            self._reads.add(answer)
        self._limit_in_flight()

    def _limit_in_flight(self) -> None:
        if self.in_flight >= self.server.settings.max_requests_per_connection:
            # Back-pressure: stop reading this client until an answer has gone out.
            self._pause()

    def _send(self, transaction_id: int, unit_id: int, reply: bytes) -> None:
        if reply and reply[0] & 0x80:
            self.errors += 1
        transport = self._transport
        if transport is not None and not transport.is_closing():
            # One write per frame: answers finishing in any order never interleave.
            transport.write(build_adu(transaction_id, unit_id, reply))

    def _refuse_write(self, transaction_id: int, unit_id: int, pdu: bytes) -> None:
        """0AH at once: this client has too many writes waiting for the line already."""
        stats = self.server.stats
        stats.write_limited += 1
        stats.exceptions += 1
        self.errors += 1
        if self._transport is not None and not self._transport.is_closing():
            reply = exception_pdu(pdu[0], ExceptionCode.GATEWAY_PATH_UNAVAILABLE)
            self._transport.write(build_adu(transaction_id, unit_id, reply))

    def pause_writing(self) -> None:
        # The client doesn't read its answers: read no more of its requests either, or their
        # answers would pile up in our buffer without bound.
        self._write_blocked = True
        self._pause()

    def resume_writing(self) -> None:
        self._write_blocked = False
        self._maybe_resume()

    def _answered(self) -> None:
        task = asyncio.current_task()
        self.answers.discard(task)
        self._reads.discard(task)
        self._maybe_resume()

    def _pause(self) -> None:
        if not self._paused:
            self._paused = True
            if self._transport is not None and not self._transport.is_closing():
                self._transport.pause_reading()

    def _maybe_resume(self) -> None:
        if not self._paused or self._write_blocked:
            return
        if self.in_flight >= self.server.settings.max_requests_per_connection:
            return
        self._paused = False
        if self._deferred:
            return  # `_take_deferred` goes on in the next pass, and resumes reading then
        if self._transport is not None and not self._transport.is_closing():
            self._transport.resume_reading()
            self._take_frames()

    async def _answer(
        self, transaction_id: int, unit_id: int, pdu: bytes, write: bool, checked: bool
    ) -> None:
        """Answer one request; `write`: it counts among the client's queued writes; `checked`:
        the front door has let it pass already."""
        try:
            if checked:
                reply = await self.server.forward(unit_id, pdu, self.client)
            else:
                reply = await self.server.reply(unit_id, pdu, self.client, self.role)
            if reply is not None:
                self._send(transaction_id, unit_id, reply)
        finally:
            # Here rather than in a done callback, which would cost the loop one more pass.
            if write:
                self._writes_waiting -= 1
            self._answered()

    def _arm_idle_timer(self) -> None:
        due = min(self._deadlines().values())
        if self.in_flight:
            # Its answers are still on their way: look again in a second at the earliest,
            # rather than spin on a deadline that has passed.
            due = max(due, self._loop.time() + 1.0)
        self._idle_due = due
        self._idle_timer = self._loop.call_at(due, self._check_idle)

    def _rearm_idle_timer(self) -> None:
        if self._idle_timer is not None:
            self._idle_timer.cancel()
        self._arm_idle_timer()

    def _deadlines(self) -> dict[str, float]:
        """When this connection is closed, and why: the earliest that applies."""
        settings = self.server.settings
        idle = settings.idle_timeout_s
        deadlines = {f"idle for {idle:g} s": self._last_data + idle}
        if self.in_flight:
            return deadlines  # waiting for the line is not the client's idling
        if self._buffer:
            # From the frame's first byte: a byte now and then must not keep it alive.
            limit = min(PARTIAL_FRAME_TIMEOUT_S, idle)
            deadlines[f"a partial frame for {limit:g} s"] = self._frame_started + limit
        if not self.served:
            first = settings.first_request_timeout_s
            deadlines[f"no complete request {first:g} s after connecting"] = (
                self.connected_at + first
            )
        return deadlines

    def _check_idle(self) -> None:
        if self._transport is None or self._transport.is_closing():
            return
        now = self._loop.time()
        if not self.in_flight:
            for reason, due in self._deadlines().items():
                if now < due:
                    continue
                stats = self.server.stats
                if reason.startswith("idle"):
                    stats.idle_closed += 1
                else:
                    stats.slow_closed += 1
                log.info("%s closed: %s", self.client, reason, extra=repeated("tcp-slow"))
                # Abort, not close: close would wait for answers a stuck client never reads,
                # and keep holding its slot.
                self.abort()
                return
        self._arm_idle_timer()


class _Answer:
    """A read's answer without a task: the bus's waiter that writes the answer frame the
    moment the reply is there, in the bus's own pass of the event loop (no task to wake)."""

    __slots__ = ("_connection", "function", "settled", "transaction_id", "unit_id")

    def __init__(self, connection: Connection, transaction_id: int, unit_id: int, function: int):
        self._connection = connection
        self.transaction_id = transaction_id
        self.unit_id = unit_id
        self.function = function
        self.settled = False

    def done(self) -> bool:
        # A client that has gone wants nothing: its read takes no bus time (`Transaction.wanted`).
        return self.settled or self._connection.gone

    def set_result(self, result: bytes | None, /) -> None:
        """The bus has the reply (or, from `set_exception`, the error's): it goes out now."""
        self.settled = True
        assert result is not None  # a taskless read is never a broadcast
        connection = self._connection
        connection._send(self.transaction_id, self.unit_id, result)
        taskless = connection._taskless
        if self in taskless:
            taskless.discard(self)
            if connection._paused:  # else `_maybe_resume` has nothing to do
                connection._maybe_resume()
            if not taskless and connection.server._drained is not None:  # else nobody waits to stop
                connection.server._settled()

    def set_exception(self, exception: BaseException, /) -> None:
        connection = self._connection
        self.set_result(
            connection.server.error_reply(self.unit_id, self.function, connection.client, exception)
        )
