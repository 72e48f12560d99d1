"""Modbus-TCP server on an asyncio Protocol.

Each connection parses MBAP frames out of what arrives and answers every request as soon as it is
ready, with its own transaction id, in any order, so a client may pipeline several (up to
`max_requests_per_connection`; beyond that the gateway stops reading that socket). A read that is
one bus transaction needs no task: checked at the front door and handed to its bus in the
same pass of the event loop, its answer written by the bus the moment the reply is there
(`_Answer`, a waiter, no task). Writes, broadcasts and reads the router splits each take a task.
Several frames in one TCP segment are all answered. A malformed header closes that connection
only: after a bad length nothing on the stream can be trusted to start a frame. A Protocol rather
than streams: no task or timer per read, which is most of the CPU a request costs here.

What one client can cost the others is bounded: `max_requests_per_connection` requests in flight
(then its socket is not read), `max_queued_writes_per_client` writes among them (beyond, 0AH), a
client that stops reading its answers is not read either (its answers wait in a buffer no larger
than those requests' replies), a frame must be complete `PARTIAL_FRAME_TIMEOUT_S` after its first
byte (however slowly the rest trickles in), a new connection must complete a request within
`first_request_timeout_s` (and a TLS client its handshake before that: `handshakes`), silence gets
`idle_timeout_s`, one address may hold at most
`max_connections_per_client` slots, and `max_connections` caps the rest. When every slot is
taken, a newcomer gets the slot of the oldest connection that has never completed a request: slow
senders can't keep well-behaved clients out, and a client that has been served is never the one
evicted. Access rules (`gateway.tcp.access`) are checked in `refusal()`, which both paths pass
through; every error becomes its exception PDU in `refusal()` or `error_reply()`.
"""

from __future__ import annotations

import asyncio
import contextlib
import ipaddress
import logging
import socket
import ssl
import time
from dataclasses import dataclass

from gateway.errors import ExceptionCode, ModbusError
from gateway.listen import cannot_listen
from gateway.logs import repeated
from gateway.modbus.functions import (
    changes_nothing,
    check_request,
    exception_pdu,
)
from gateway.tcp.access import AccessPolicy
from gateway.tcp.connection import Connection, RequestRoute
from gateway.tcp.handshakes import HandshakeWatch
from gateway.tcp.settings import TcpSettings as TcpSettings
from gateway.tcp.settings import TlsListener as TlsListener
from gateway.tcp.stats import TcpStats

log = logging.getLogger(__name__)


# The kernel's buffers per client. Autotuned they grow to megabytes: requests of a client we have
# stopped reading, answers to a client that doesn't read. A Modbus client has a few hundred bytes
# in flight; these limits keep what a hostile one can make us hold small.
SOCKET_BUFFER_BYTES = 32 * 1024


@dataclass(frozen=True, slots=True)
class ClientStatus:
    """One open Modbus-TCP connection, as a diagnostics page shows it."""

    client: str
    """"tcp:ADDRESS:PORT", as the bus, the traffic monitor and the audit name it."""
    connected_at: float
    """Wall clock (epoch seconds)."""
    requests: int
    errors: int
    """Requests answered with an exception (the drive's, or the gateway's: 0AH, 0BH...)."""
    in_flight: int
    tls: bool
    role: str | None


class ModbusTcpServer:
    def __init__(self, settings: TcpSettings, route: RequestRoute) -> None:
        self.settings = settings
        self.stats = TcpStats()
        self.route = route
        """Where each request goes: `execute` in a task, or a read at once (`submit`)."""
        self._drained: asyncio.Future[None] | None = None
        """Set while `stop` waits for the taskless reads' answers to go out."""
        self._server: asyncio.Server | None = None
        self._tls_server: asyncio.Server | None = None
        self._connections: set[Connection] = set()
        self.handshakes: HandshakeWatch | None = None
        """The TLS listener's handshakes, timed and counted."""
        self._networks = [ipaddress.ip_network(n, strict=False) for n in settings.allowed_networks]
        # None without rules: the common case costs one attribute test per request.
        self.access = AccessPolicy(settings.access) if settings.access else None

    def update(self, settings: TcpSettings) -> None:
        """A reload: new rules for the next requests and connections; the listeners (host, port,
        TLS) stay as they are and open connections stay open."""
        self.settings = settings
        self._networks = [ipaddress.ip_network(n, strict=False) for n in settings.allowed_networks]
        self.access = AccessPolicy(settings.access) if settings.access else None

    @property
    def port(self) -> int:
        """The plain listener's bound port (useful when configured as 0); the TLS one's when
        there is no plain listener."""
        server = self._server or self._tls_server
        assert server is not None, "start() first"
        return int(server.sockets[0].getsockname()[1])

    @property
    def tls_port(self) -> int | None:
        if self._tls_server is None:
            return None
        return int(self._tls_server.sockets[0].getsockname()[1])

    async def start(self) -> None:
        settings = self.settings
        if settings.plain:
            self._server = await self._listen(settings.host, settings.port, None)
            log.info("Modbus-TCP listening on %s:%d", settings.host, self.port)
        tls = settings.tls
        if tls is not None:
            try:
                context = tls.context()
            except (OSError, ssl.SSLError) as exc:
                raise cannot_listen(
                    "Modbus/TCP Security", tls.host, tls.port, "modbus_tcp.tls files", exc
                ) from exc
            self.handshakes = HandshakeWatch(self.stats, settings.first_request_timeout_s)
            self.handshakes.watch(context)
            self._tls_server = await self._listen(tls.host, tls.port, context)
            log.info("Modbus/TCP Security (TLS) listening on %s:%d", tls.host, self.tls_port)

    async def _listen(self, host: str, port: int, context: ssl.SSLContext | None) -> asyncio.Server:
        loop = asyncio.get_running_loop()
        what = "Modbus-TCP" if context is None else "Modbus/TCP Security"
        keys = "modbus_tcp.host/port" if context is None else "modbus_tcp.tls.host/port"
        try:
            server = await loop.create_server(
                lambda: Connection(self),
                host,
                port,
                reuse_address=True,
                ssl=context,
                # asyncio's default is 60 s: a stalled handshake would hold a socket that long.
                ssl_handshake_timeout=None if context is None else self._handshake_timeout_s(),
            )
        except OSError as exc:
            raise cannot_listen(what, host, port, keys, exc) from exc
        for sock in server.sockets:  # accepted connections inherit them
            for option in (socket.SO_SNDBUF, socket.SO_RCVBUF):
                with contextlib.suppress(OSError):
                    sock.setsockopt(socket.SOL_SOCKET, option, SOCKET_BUFFER_BYTES)
        return server

    def _handshake_timeout_s(self) -> float:
        assert self.handshakes is not None, "watched before listening"
        return self.handshakes.timeout_s

    def stop_accepting(self) -> None:
        for server in (self._server, self._tls_server):
            if server is not None:
                server.close()

    async def stop(self, grace_s: float = 0.5) -> None:
        """Stop accepting, give answers in flight `grace_s` to go out, then close connections."""
        self.stop_accepting()
        loop = asyncio.get_running_loop()
        deadline = loop.time() + grace_s
        answers = {task for c in self._connections for task in c.answers}
        if answers:
            await asyncio.wait(answers, timeout=grace_s)
        if any(c.settling for c in self._connections):
            self._drained = loop.create_future()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._drained, max(deadline - loop.time(), 0.0))
            self._drained = None
        for connection in list(self._connections):
            connection.close()
        if self.handshakes is not None:
            self.handshakes.stop()
        if self._server is not None:
            try:
                await asyncio.wait_for(self._server.wait_closed(), 1.0)
            except TimeoutError:
                log.warning("Modbus-TCP: connections still closing after 1 s")

    # -- called by connections -----------------------------------------------------------------

    def admit(self, connection: Connection) -> bool:
        if not self._allowed(connection.host):
            self.stats.refused += 1
            log.warning(
                "%s refused: not in modbus_tcp.allowed_networks",
                connection.client,
                extra=repeated("tcp-not-allowed"),
            )
            return False
        same_host = sum(1 for other in self._connections if other.host == connection.host)
        if same_host >= self.settings.per_client_limit:
            self.stats.refused += 1
            log.warning(
                "%s refused: %d connections open from %s (modbus_tcp.max_connections_per_client)",
                connection.client,
                same_host,
                connection.host,
                extra=repeated("tcp-per-client-limit"),
            )
            return False
        if len(self._connections) >= self.settings.max_connections and not self._evict_one():
            self.stats.refused += 1
            log.warning(
                "%s refused: %d connections open (modbus_tcp.max_connections)",
                connection.client,
                len(self._connections),
                extra=repeated("tcp-max-connections"),
            )
            return False
        self._connections.add(connection)
        self.stats.accepted += 1
        self.stats.active.add(connection.client)
        return True

    def _evict_one(self) -> bool:
        """Free a slot: close the oldest connection that has never completed a request."""
        silent = [c for c in self._connections if not c.served and not c.closing]
        if not silent:
            return False
        oldest = min(silent, key=lambda connection: connection.connected_at)
        self.stats.evicted += 1
        log.info(
            "%s closed to make room: it never completed a request",
            oldest.client,
            extra=repeated("tcp-evicted"),
        )
        oldest.abort()
        self._connections.discard(oldest)  # its slot is free now, whatever its close does
        return True

    def clients(self) -> list[ClientStatus]:
        """The open connections, oldest first: a few attributes each, for a diagnostics page."""
        loop = asyncio.get_running_loop()
        to_wall = time.time() - loop.time()
        return [
            ClientStatus(
                c.client,
                c.connected_at + to_wall,
                c.requests,
                c.errors,
                c.in_flight,
                c.tls,
                c.role,
            )
            for c in sorted(self._connections, key=lambda c: c.connected_at)
        ]

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

    async def reply(
        self, unit_id: int, pdu: bytes, client: str, role: str | None = None
    ) -> bytes | None:
        """The reply PDU for one request; every error becomes an exception PDU here, only here."""
        refusal = self.refusal(unit_id, pdu, client, role)
        if refusal is not None:
            return refusal
        return await self.forward(unit_id, pdu, client)

    def refusal(self, unit_id: int, pdu: bytes, client: str, role: str | None) -> bytes | None:
        """The exception PDU for a request refused at the front door; None: it may pass."""
        function = pdu[0]
        malformed = check_request(pdu)
        if malformed is not None:
            # Answered at the front door, without bus time: a drive may misbehave on it, and it
            # would cost every other client the line.
            self.stats.malformed_requests[malformed.reason] += 1
            self.stats.exceptions += 1
            detail = f"{malformed.reason}: {malformed.detail}"
            log.debug("%s unit %d: %s refused: %s", client, unit_id, pdu[:8].hex(" "), detail)
            return exception_pdu(function, malformed.exception_code)
        if self.settings.read_only and not changes_nothing(pdu):
            self.stats.denied += 1
            self.stats.exceptions += 1
            log.debug("%s unit %d: %02XH refused: modbus_tcp.read_only", client, unit_id, function)
            return exception_pdu(function, ExceptionCode.ILLEGAL_FUNCTION)
        if self.access is not None:
            refusal = self.access.check(unit_id, pdu, role)
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
        return None

    async def forward(self, unit_id: int, pdu: bytes, client: str) -> bytes | None:
        """The handler's reply to a request the front door let pass."""
        try:
            reply = await self.route.execute(unit_id, pdu, client)
        except Exception as exc:
            return self.error_reply(unit_id, pdu[0], client, exc)
        if reply is None:  # a broadcast: no drive answers it
            return pdu if self.settings.broadcast_reply else None
        return reply

    def error_reply(self, unit_id: int, function: int, client: str, exc: BaseException) -> bytes:
        """The exception PDU a failed request is answered with."""
        self.stats.exceptions += 1
        if isinstance(exc, ModbusError):
            log.debug("%s unit %d: %s", client, unit_id, exc)
            return exception_pdu(function, exc.code)
        # A bug must cost one answer, not the connection: log it loudly.
        log.error("%s unit %d: unexpected error", client, unit_id, exc_info=exc)
        return exception_pdu(function, ExceptionCode.SERVER_DEVICE_FAILURE)

    def _settled(self) -> None:
        """A taskless read's answer went out (or its connection went): `stop` may be waiting."""
        drained = self._drained
        if drained is None or drained.done():
            return
        if not any(c.settling for c in self._connections):
            drained.set_result(None)
