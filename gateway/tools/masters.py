"""One request at a time to a drive: on the serial line itself, or through a running gateway.

Both raise the gateway's own line errors (`ReplyTimeout`, `BadReply`, `PortError`), so the tools
above them treat a silent drive the same way whichever path they took. Exception replies come
back as exception PDUs: what they mean is for the caller to say.

`RtuMaster` is the bus's `SerialLine` with a tool's settings (no retries, a short drain), so the
field tools time and frame requests exactly as the service does. The line lives on an event loop;
the master keeps a private one and runs each request on it to the end.
"""

from __future__ import annotations

import asyncio
import socket
from dataclasses import dataclass
from typing import Protocol
from urllib.parse import urlsplit

from gateway.bus.line import LineSettings, SerialLine
from gateway.errors import BadReply, MalformedFrame, PortError, ReplyTimeout
from gateway.modbus.mbap import HEADER_LENGTH, build_adu, parse_header
from gateway.modbus.rtu import build_frame
from gateway.modbus.timing import CharacterFormat

DEFAULT_GATEWAY_PORT = 5020


class Master(Protocol):
    @property
    def where(self) -> str:
        """Where requests go, for messages: "/dev/ttyUSB0 at 19200 baud 8E1"."""
        ...

    def request(self, address: int, pdu: bytes) -> bytes:
        """The reply PDU (possibly an exception PDU) from the drive at `address`."""
        ...

    def close(self) -> None: ...


@dataclass(frozen=True, slots=True)
class SerialOptions:
    port: str
    baudrate: int = 19200
    parity: str = "E"
    stopbits: int = 1
    timeout_s: float = 0.5
    char_timeout_s: float = 0.02
    """Silence that ends a reply; USB adapters deliver bytes in bursts."""
    drain_s: float = 0.05
    """After a timeout, listen this long for a late reply so it isn't taken for the next one."""

    @property
    def char_format(self) -> CharacterFormat:
        return CharacterFormat(self.baudrate, self.parity, self.stopbits, 8)

    def describe(self) -> str:
        return f"{self.port} at {self.baudrate} baud 8{self.parity}{self.stopbits}"


class RtuMaster:
    def __init__(self, options: SerialOptions) -> None:
        self.options = options
        self._loop = asyncio.new_event_loop()
        char_format = options.char_format
        self.line = SerialLine(
            LineSettings(
                port=options.port,
                char_format=char_format,
                gap_s=char_format.t35_s,
                char_timeout_s=options.char_timeout_s,
                drain_s=options.drain_s,
                turnaround_s=0.1,
            )
        )
        try:
            self._loop.run_until_complete(self._open())
        except BaseException:
            self._loop.close()
            raise

    @property
    def where(self) -> str:
        return self.options.describe()

    def request(self, address: int, pdu: bytes) -> bytes:
        frame = build_frame(address, pdu)
        exchange = self._loop.run_until_complete(
            self.line.transact(frame, expect_reply=True, timeout_s=self.options.timeout_s)
        )
        assert exchange.reply_pdu is not None  # a request with a reply expected has one
        return exchange.reply_pdu

    def close(self) -> None:
        if not self._loop.is_closed():
            self.line.close()
            self._loop.close()

    async def _open(self) -> None:
        self.line.open()


def parse_via(url: str) -> tuple[str, int]:
    """ "tcp://10.0.0.5:5020" → ("10.0.0.5", 5020); the port defaults to the gateway's 5020."""
    parts = urlsplit(url)
    if parts.scheme != "tcp" or not parts.hostname:
        raise ValueError(f"{url!r}: expected tcp://HOST:PORT, e.g. tcp://127.0.0.1:5020")
    try:
        port = parts.port
    except ValueError as exc:
        raise ValueError(f"{url!r}: {exc}") from None
    return parts.hostname, port or DEFAULT_GATEWAY_PORT


class TcpMaster:
    """A Modbus-TCP client of a running gateway; the drive's address is the unit id."""

    def __init__(self, host: str, port: int, timeout_s: float) -> None:
        self.host = host
        self.port = port
        self._transaction = 0
        try:
            self._socket = socket.create_connection((host, port), timeout=timeout_s)
        except OSError as exc:
            raise PortError(f"cannot connect to the gateway at {host}:{port}: {exc}") from exc

    @property
    def where(self) -> str:
        return f"the gateway at tcp://{self.host}:{self.port}"

    def request(self, address: int, pdu: bytes) -> bytes:
        self._transaction = (self._transaction + 1) & 0xFFFF
        try:
            self._socket.sendall(build_adu(self._transaction, address, pdu))
            header = parse_header(self._receive(HEADER_LENGTH))
            reply = self._receive(header.pdu_length)
        except TimeoutError as exc:
            raise ReplyTimeout(f"{self.where} did not answer in time") from exc
        except MalformedFrame as exc:
            raise BadReply("mbap", f"{self.where} sent a malformed frame: {exc}") from exc
        except OSError as exc:
            raise PortError(f"connection to {self.where} failed: {exc}") from exc
        if header.transaction_id != self._transaction or header.unit_id != address:
            raise BadReply("mbap", f"{self.where} answered another request")
        return reply

    def _receive(self, size: int) -> bytes:
        data = bytearray()
        while len(data) < size:
            chunk = self._socket.recv(size - len(data))
            if not chunk:
                raise ConnectionError("the gateway closed the connection")
            data += chunk
        return bytes(data)

    def close(self) -> None:
        self._socket.close()
