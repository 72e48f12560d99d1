"""Modbus-TCP server on asyncio streams.

Each connection reads MBAP frames in a loop and answers every request in its own task, so a client
may pipeline several requests (up to `max_requests_per_connection`) and get each answer with its
own transaction id as soon as it is ready, in any order. A malformed header closes that connection
only: after a bad length nothing on the stream can be trusted to start a frame.
"""

from __future__ import annotations

import asyncio
import contextlib
import ipaddress
import logging
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field

from gateway.errors import MalformedFrame, ModbusError
from gateway.modbus.functions import WRITES, exception_pdu
from gateway.modbus.mbap import HEADER_LENGTH, MbapHeader, build_adu, parse_header

log = logging.getLogger(__name__)

RequestHandler = Callable[[int, bytes, str], Awaitable[bytes | None]]
"""(unit id, request PDU, client) -> reply PDU, or None when nothing answers (a broadcast)."""

ILLEGAL_FUNCTION = 0x01
SERVER_DEVICE_FAILURE = 0x04
# Once a header has arrived, the rest of its frame follows at once; a client that stops halfway
# is broken, and waiting for it would hold a connection slot.
FRAME_REST_TIMEOUT_S = 5.0


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
        self._handler = handler
        self._server: asyncio.Server | None = None
        # Connection handler tasks and their writers. Closing the writer ends a handler; cancelling
        # it would trip asyncio's own stream callback on Python 3.11.
        self._connections: dict[asyncio.Task[None], asyncio.StreamWriter] = {}
        self._networks = [ipaddress.ip_network(n, strict=False) for n in settings.allowed_networks]

    @property
    def port(self) -> int:
        """The bound port (useful when configured as 0)."""
        assert self._server is not None, "start() first"
        return int(self._server.sockets[0].getsockname()[1])

    async def start(self) -> None:
        self._server = await asyncio.start_server(
            self._accept, self.settings.host, self.settings.port, reuse_address=True
        )
        log.info("Modbus-TCP listening on %s:%d", self.settings.host, self.port)

    def stop_accepting(self) -> None:
        if self._server is not None:
            self._server.close()

    async def stop(self, grace_s: float = 0.5) -> None:
        """Stop accepting, give answers in flight `grace_s` to go out, then close connections."""
        self.stop_accepting()
        if self._connections:
            await asyncio.wait(set(self._connections), timeout=grace_s)
        for writer in list(self._connections.values()):
            writer.close()
        if self._connections:
            await asyncio.wait(set(self._connections), timeout=1.0)
        if self._server is not None:
            with contextlib.suppress(Exception):
                await asyncio.wait_for(self._server.wait_closed(), 1.0)

    # -- connections ---------------------------------------------------------------------------

    async def _accept(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        peer = writer.get_extra_info("peername") or ("?", 0)
        client = f"tcp:{peer[0]}:{peer[1]}"
        if not self._allowed(peer[0]):
            self.stats.refused += 1
            log.warning("%s refused: not in modbus_tcp.allowed_networks", client)
            writer.close()
            return
        if len(self._connections) >= self.settings.max_connections:
            self.stats.refused += 1
            log.warning(
                "%s refused: %d connections open (modbus_tcp.max_connections)",
                client,
                len(self._connections),
            )
            writer.close()
            return
        self._connections[task] = writer
        self.stats.accepted += 1
        self.stats.active.add(client)
        try:
            await self._serve(reader, writer, client)
        finally:
            self._connections.pop(task, None)
            self.stats.active.discard(client)
            writer.close()
            with contextlib.suppress(Exception):
                await asyncio.wait_for(writer.wait_closed(), 1.0)

    def _allowed(self, host: str) -> bool:
        if not self._networks:
            return True
        try:
            address = ipaddress.ip_address(host)
        except ValueError:
            return False
        return any(address in network for network in self._networks)

    async def _serve(
        self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter, client: str
    ) -> None:
        slots = asyncio.Semaphore(self.settings.max_requests_per_connection)
        answers: set[asyncio.Task[None]] = set()
        try:
            while True:
                try:
                    raw = await asyncio.wait_for(
                        reader.readexactly(HEADER_LENGTH), self.settings.idle_timeout_s
                    )
                except TimeoutError:
                    self.stats.idle_closed += 1
                    log.info("%s closed: idle for %.0f s", client, self.settings.idle_timeout_s)
                    return
                header = parse_header(raw)
                pdu = await asyncio.wait_for(
                    reader.readexactly(header.pdu_length), FRAME_REST_TIMEOUT_S
                )
                # Back-pressure: with too many answers outstanding, stop reading this client.
                await slots.acquire()
                self.stats.requests += 1
                answer = asyncio.create_task(self._answer(writer, header, pdu, client))
                answers.add(answer)

                def finished(task: asyncio.Task[None]) -> None:
                    answers.discard(task)
                    slots.release()

                answer.add_done_callback(finished)
        except MalformedFrame as exc:
            self.stats.malformed += 1
            log.warning("%s closed: malformed frame (%s)", client, exc)
        except (asyncio.IncompleteReadError, ConnectionError, TimeoutError):
            pass
        finally:
            if answers:
                # Answers already on their way still go out; then the connection closes.
                await asyncio.wait(answers, timeout=2.0)
            for answer in answers:
                answer.cancel()

    async def _answer(
        self, writer: asyncio.StreamWriter, header: MbapHeader, pdu: bytes, client: str
    ) -> None:
        reply = await self._reply(header.unit_id, pdu, client)
        if reply is None:
            return
        if writer.is_closing():
            return
        # One write call per frame: frames from concurrent answers never interleave.
        writer.write(build_adu(header.transaction_id, header.unit_id, reply))
        with contextlib.suppress(ConnectionError):
            await writer.drain()

    async def _reply(self, unit_id: int, pdu: bytes, client: str) -> bytes | None:
        """The reply PDU for one request; every error becomes an exception PDU here, only here."""
        function = pdu[0]
        if self.settings.read_only and function in WRITES:
            self.stats.denied += 1
            self.stats.exceptions += 1
            return exception_pdu(function, ILLEGAL_FUNCTION)
        try:
            reply = await self._handler(unit_id, pdu, client)
        except ModbusError as exc:
            self.stats.exceptions += 1
            log.debug("%s unit %d: %s", client, unit_id, exc)
            return exception_pdu(function, exc.code)
        except Exception:  # a bug must cost one answer, not the connection: log it loudly
            log.exception("%s unit %d: unexpected error", client, unit_id)
            return exception_pdu(function, SERVER_DEVICE_FAILURE)
        if reply is None:  # a broadcast: no drive answers it
            return pdu if self.settings.broadcast_reply else None
        return reply
