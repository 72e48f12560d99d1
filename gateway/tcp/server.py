"""Modbus-TCP server on an asyncio Protocol.

Each connection parses MBAP frames out of what arrives and answers every request in its own task,
so a client may pipeline several requests (up to `max_requests_per_connection`; beyond that the
gateway stops reading that socket) and gets each answer with its own transaction id as soon as it
is ready, in any order. Several frames in one TCP segment are all answered. A malformed header
closes that connection only: after a bad length nothing on the stream can be trusted to start a
frame. A Protocol rather than streams: no task or timer per read, which is most of the CPU a
request costs here.

What one client can cost the others is bounded: `max_requests_per_connection` requests in flight
(then its socket is not read), a client that stops reading its answers is not read either (its
answers wait in a buffer no larger than those requests' replies), a half-sent frame is given
`PARTIAL_FRAME_TIMEOUT_S`, silence `idle_timeout_s`, and `max_connections` caps the rest. Access
rules (`gateway.tcp.access`) are checked in `reply()`, where every refusal becomes its exception.
"""

from __future__ import annotations

import asyncio
import contextlib
import ipaddress
import logging
import socket
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field

from gateway.errors import ExceptionCode, MalformedFrame, ModbusError
from gateway.modbus.functions import changes_nothing, exception_pdu, lookup
from gateway.modbus.mbap import HEADER_LENGTH, build_adu, parse_header
from gateway.tcp.access import AccessPolicy, AccessRule

log = logging.getLogger(__name__)

RequestHandler = Callable[[int, bytes, str], Awaitable[bytes | None]]
"""(unit id, request PDU, client) -> reply PDU, or None when nothing answers (a broadcast)."""

# Once part of a frame has arrived, the rest follows at once; a client that stops halfway is
# broken, and waiting for it the whole idle timeout would hold a connection slot.
PARTIAL_FRAME_TIMEOUT_S = 5.0
# The kernel's buffers per client. Autotuned they grow to megabytes: requests of a client we have
# stopped reading, answers to a client that doesn't read. A Modbus client has a few hundred bytes
# in flight; these limits keep what a hostile one can make us hold small.
SOCKET_BUFFER_BYTES = 32 * 1024


@dataclass(frozen=True, slots=True)
class TcpSettings:
    host: str = "0.0.0.0"
    port: int = 5020
    max_connections: int = 32
    idle_timeout_s: float = 300.0
    max_requests_per_connection: int = 16
    broadcast_reply: bool = True
    allowed_networks: tuple[str, ...] = ()
    read_only: bool = False
    access: tuple[AccessRule, ...] = ()
    """First match wins; none: every request may pass (see `gateway.tcp.access`)."""


@dataclass(slots=True)
class TcpStats:
    connections: int = 0
    accepted: int = 0
    refused: int = 0
    malformed: int = 0
    idle_closed: int = 0
    requests: int = 0
    exceptions: int = 0
    denied: int = 0
    active: set[str] = field(default_factory=set)


class ModbusTcpServer:
    def __init__(self, settings: TcpSettings, handler: RequestHandler) -> None:
        self.settings = settings
        self.stats = TcpStats()
        self.handler = handler
        self._server: asyncio.Server | None = None
        self._connections: set[Connection] = set()
        self._networks = [ipaddress.ip_network(n, strict=False) for n in settings.allowed_networks]
        # None without rules: the common case costs one attribute test per request.
        self.access = AccessPolicy(settings.access) if settings.access else None

    @property
    def port(self) -> int:
        """The bound port (useful when configured as 0)."""
        assert self._server is not None, "start() first"
        return int(self._server.sockets[0].getsockname()[1])

    async def start(self) -> None:
        loop = asyncio.get_running_loop()
        self._server = await loop.create_server(
            lambda: Connection(self), self.settings.host, self.settings.port, reuse_address=True
        )
        for sock in self._server.sockets:  # accepted connections inherit them
            for option in (socket.SO_SNDBUF, socket.SO_RCVBUF):
                with contextlib.suppress(OSError):
                    sock.setsockopt(socket.SOL_SOCKET, option, SOCKET_BUFFER_BYTES)
        log.info("Modbus-TCP listening on %s:%d", self.settings.host, self.port)

    def stop_accepting(self) -> None:
        if self._server is not None:
            self._server.close()

    async def stop(self, grace_s: float = 0.5) -> None:
        """Stop accepting, give answers in flight `grace_s` to go out, then close connections."""
        self.stop_accepting()
        answers = {task for c in self._connections for task in c.answers}
        if answers:
            await asyncio.wait(answers, timeout=grace_s)
        for connection in list(self._connections):
            connection.close()
        if self._server is not None:
            try:
                await asyncio.wait_for(self._server.wait_closed(), 1.0)
            except TimeoutError:
                log.warning("Modbus-TCP: connections still closing after 1 s")

    # -- called by connections -----------------------------------------------------------------

    def admit(self, connection: Connection) -> bool:
        if not self._allowed(connection.host):
            self.stats.refused += 1
            log.warning("%s refused: not in modbus_tcp.allowed_networks", connection.client)
            return False
        if len(self._connections) >= self.settings.max_connections:
            self.stats.refused += 1
            log.warning(
                "%s refused: %d connections open (modbus_tcp.max_connections)",
                connection.client,
                len(self._connections),
            )
            return False
        self._connections.add(connection)
        self.stats.accepted += 1
        self.stats.active.add(connection.client)
        return True

    def forget(self, connection: Connection) -> None:
        self._connections.discard(connection)
        self.stats.active.discard(connection.client)

    def _allowed(self, host: str) -> bool:
        if not self._networks:
            return True
        try:
            address = ipaddress.ip_address(host)
        except ValueError:
            return False
        return any(address in network for network in self._networks)

    async def reply(self, unit_id: int, pdu: bytes, client: str) -> bytes | None:
        """The reply PDU for one request; every error becomes an exception PDU here, only here."""
        function = pdu[0]
        if self.settings.read_only and not changes_nothing(pdu):
            self.stats.denied += 1
            self.stats.exceptions += 1
            log.debug("%s unit %d: %02XH refused: modbus_tcp.read_only", client, unit_id, function)
            return exception_pdu(function, ExceptionCode.ILLEGAL_FUNCTION)
        if self.access is not None:
            refusal = self.access.check(unit_id, pdu)
            if refusal is not None:
                self.stats.denied += 1
                self.stats.exceptions += 1
                log.debug(
                    "%s unit %d: %s refused by modbus_tcp.access rule %s (exception %02XH)",
                    client,
                    unit_id,
                    pdu[:5].hex(" "),
                    self.access.rules[refusal.rule].label,
                    refusal.code,
                )
                return exception_pdu(function, refusal.code)
        try:
            reply = await self.handler(unit_id, pdu, client)
        except ModbusError as exc:
            self.stats.exceptions += 1
            log.debug("%s unit %d: %s", client, unit_id, exc)
            return exception_pdu(function, exc.code)
        except Exception:  # a bug must cost one answer, not the connection: log it loudly
            log.exception("%s unit %d: unexpected error", client, unit_id)
            return exception_pdu(function, ExceptionCode.SERVER_DEVICE_FAILURE)
        if reply is None:  # a broadcast: no drive answers it
            return pdu if self.settings.broadcast_reply else None
        return reply


class Connection(asyncio.Protocol):
    """One Modbus-TCP client: frames in, answers out, in whatever order they are ready."""

    def __init__(self, server: ModbusTcpServer) -> None:
        self.server = server
        self.client = "tcp:?:0"
        self.host = "?"
        self.answers: set[asyncio.Task[None]] = set()
        self._reads: set[asyncio.Task[None]] = set()
        """Answers to pure reads: nobody will receive them once the client has gone."""
        self._transport: asyncio.Transport | None = None
        self._buffer = bytearray()
        self._paused = False
        self._write_blocked = False
        self._loop = asyncio.get_running_loop()
        self._last_data = self._loop.time()
        self._idle_timer: asyncio.TimerHandle | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self._transport = transport
        peer = transport.get_extra_info("peername") or ("?", 0)
        self.host = str(peer[0])
        self.client = f"tcp:{peer[0]}:{peer[1]}"
        if not self.server.admit(self):
            transport.close()
            return
        self._arm_idle_timer()

    def connection_lost(self, exc: Exception | None) -> None:
        self.server.forget(self)
        if self._idle_timer is not None:
            self._idle_timer.cancel()
        # A read nobody will receive must not cost bus time: cancelling its answer takes it out
        # of the queue (a read shared with other clients still goes out for them). Writes go on:
        # the client sent them, and a half-done split write is worse than a finished one.
        for read in self._reads:
            read.cancel()

    def close(self) -> None:
        if self._transport is not None:
            self._transport.close()

    def data_received(self, data: bytes) -> None:
        self._last_data = self._loop.time()
        self._buffer += data
        self._take_frames()

    def _take_frames(self) -> None:
        settings = self.server.settings
        buffer = self._buffer
        while len(buffer) >= HEADER_LENGTH and not self._paused:
            try:
                header = parse_header(bytes(buffer[:HEADER_LENGTH]))
            except MalformedFrame as exc:
                self.server.stats.malformed += 1
                log.warning("%s closed: malformed frame (%s)", self.client, exc)
                self.close()
                buffer.clear()
                return
            end = HEADER_LENGTH + header.pdu_length
            if len(buffer) < end:
                return
            pdu = bytes(buffer[HEADER_LENGTH:end])
            del buffer[:end]
            self.server.stats.requests += 1
            answer = self._loop.create_task(
                self._answer(header.transaction_id, header.unit_id, pdu)
            )
            self.answers.add(answer)
            if lookup(pdu[0]).coalescable:  # a pure read
                self._reads.add(answer)
            if len(self.answers) >= settings.max_requests_per_connection:
                # Back-pressure: stop reading this client until an answer has gone out.
                self._pause()

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
        if len(self.answers) >= self.server.settings.max_requests_per_connection:
            return
        self._paused = False
        if self._transport is not None and not self._transport.is_closing():
            self._transport.resume_reading()
            self._take_frames()

    async def _answer(self, transaction_id: int, unit_id: int, pdu: bytes) -> None:
        try:
            reply = await self.server.reply(unit_id, pdu, self.client)
            transport = self._transport
            if reply is None or transport is None or transport.is_closing():
                return
            # One write per frame: answers finishing in any order never interleave.
            transport.write(build_adu(transaction_id, unit_id, reply))
        finally:
            # Here rather than in a done callback, which would cost the loop one more pass.
            self._answered()

    def _arm_idle_timer(self) -> None:
        settings = self.server.settings
        limit = settings.idle_timeout_s
        if self._buffer:
            limit = min(PARTIAL_FRAME_TIMEOUT_S, limit)
        if self.answers:
            limit = settings.idle_timeout_s  # waiting for the line is not the client's idling
        due = self._last_data + limit
        if self.answers:
            # Its answers are still on their way: look again in a second at the earliest,
            # rather than spin on a deadline that has passed.
            due = max(due, self._loop.time() + 1.0)
        self._idle_timer = self._loop.call_at(due, self._check_idle, limit)

    def _check_idle(self, limit: float) -> None:
        if self._transport is None or self._transport.is_closing():
            return
        if self._loop.time() - self._last_data >= limit and not self.answers:
            self.server.stats.idle_closed += 1
            reason = "a partial frame" if self._buffer else "idle"
            log.info("%s closed: %s for %.0f s", self.client, reason, limit)
            # Abort, not close: close would wait for answers a stuck client never reads, and
            # keep holding its slot.
            self._transport.abort()
            return
        self._arm_idle_timer()
