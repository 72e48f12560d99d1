"""Modbus-TCP clients for the benchmark: one request outstanding each, every reply checked."""

from __future__ import annotations

import asyncio
import contextlib
import struct
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import cast

DEAD_DRIVE_REPLY = bytes.fromhex("83 0B")


@dataclass(frozen=True, slots=True)
class Target:
    """A request and the one reply that is right for it."""

    unit_id: int
    pdu: bytes
    expected: bytes


@dataclass
class LoadResult:
    answered: int = 0
    errors: int = 0
    wrong: int = 0
    dead_answers: int = 0
    latencies_s: list[float] = field(default_factory=list)
    answered_by_unit: Counter[int] = field(default_factory=Counter)

    @classmethod
    def merged(cls, results: list[LoadResult]) -> LoadResult:
        """The clients of several lines as one load."""
        total = cls()
        for each in results:
            total.answered += each.answered
            total.errors += each.errors
            total.wrong += each.wrong
            total.dead_answers += each.dead_answers
            total.latencies_s += each.latencies_s
            total.answered_by_unit.update(each.answered_by_unit)
        return total


async def run_clients(
    port: int,
    reads: list[Target],
    dead_units: frozenset[int],
    measuring: asyncio.Event,
    stop: asyncio.Event,
    dead_pause_s: float = 0.0,
) -> LoadResult:
    """One connection per target in `reads`, each asking its read again and again until
    `stop`; only replies while `measuring` is set count. A client of a dead drive (answered
    0BH) waits `dead_pause_s` before asking again, as a poller would, instead of spinning."""
    result = LoadResult()
    loop = asyncio.get_running_loop()
    clients: list[_Client] = []
    try:
        for target in reads:
            client = _Client(target, dead_units, measuring, stop, result, dead_pause_s, loop)
            clients.append(client)
            await _connect(loop, client, port)
        await asyncio.gather(*(client.done for client in clients))
    finally:
        for client in clients:
            client.close()
    return result


async def _connect(loop: asyncio.AbstractEventLoop, client: _Client, port: int) -> None:
    await loop.create_connection(lambda: client, "127.0.0.1", port)


class _Client(asyncio.Protocol):
    """One SCADA client with one request outstanding: asks, checks the reply, asks again.

    A protocol rather than a stream reader: at 32 lines the bench's 256 clients answer some
    5,000 replies a second from one process, and two `readexactly` awaits per reply made the
    clients a core-sharing neighbour the gateway's figures would pay for."""

    def __init__(
        self,
        target: Target,
        dead_units: frozenset[int],
        measuring: asyncio.Event,
        stop: asyncio.Event,
        result: LoadResult,
        dead_pause_s: float,
        loop: asyncio.AbstractEventLoop,
    ) -> None:
        self.target = target
        self._rest_of_header = struct.pack(">HHB", 0, len(target.pdu) + 1, target.unit_id)
        self._dead = target.unit_id in dead_units
        self._pause_s = dead_pause_s if self._dead else 0.0
        self._measuring, self._stop, self._result = measuring, stop, result
        self._loop = loop
        self._transport: asyncio.Transport | None = None
        self._tid = 0
        self._started = 0.0
        self._buffer = b""
        self.done: asyncio.Future[None] = loop.create_future()

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self._transport = cast(asyncio.Transport, transport)  # uvloop's isn't a subclass
        self._ask()

    def _ask(self) -> None:
        transport = self._transport
        if transport is None or transport.is_closing():
            return
        if self._stop.is_set():
            transport.close()
            return
        self._tid = tid = (self._tid + 1) & 0xFFFF
        self._started = time.perf_counter()
        transport.write(tid.to_bytes(2, "big") + self._rest_of_header + self.target.pdu)

    def data_received(self, data: bytes) -> None:
        buffer = self._buffer + data if self._buffer else data
        while len(buffer) >= 7:
            end = 6 + int.from_bytes(buffer[4:6], "big")
            if len(buffer) < end:
                break
            self._answered(buffer[:end], time.perf_counter() - self._started)
            buffer = buffer[end:]
        self._buffer = buffer

    def _answered(self, reply: bytes, latency: float) -> None:
        if self._measuring.is_set():
            self._count(reply, latency)
        if self._pause_s:
            self._loop.call_later(self._pause_s, self._ask)
        else:
            self._ask()

    def _count(self, reply: bytes, latency: float) -> None:
        result, target = self._result, self.target
        pdu = reply[7:]
        if int.from_bytes(reply[:2], "big") != self._tid or reply[6] != target.unit_id:
            result.wrong += 1
        elif self._dead:
            result.dead_answers += pdu == DEAD_DRIVE_REPLY
            result.wrong += pdu != DEAD_DRIVE_REPLY
        elif pdu == target.expected:
            result.answered += 1
            result.answered_by_unit[target.unit_id] += 1
            result.latencies_s.append(latency)
        elif pdu[0] & 0x80:
            result.errors += 1
        else:
            result.wrong += 1

    def connection_lost(self, exc: Exception | None) -> None:
        if self.done.done():
            return
        if self._stop.is_set():
            self.done.set_result(None)
        else:  # the gateway closed it: the case is void, as a client would see it
            self.done.set_exception(
                ConnectionError(f"connection closed by the gateway mid-case ({exc})")
            )

    def close(self) -> None:
        if self._transport is not None:
            self._transport.close()


STOP_COMMAND = struct.pack(">BHH", 6, 0x2000, 5)
"""INVT's control word 2000H = 5, stop: what a broadcast flood sends (the drives stand still)."""


def flood_request(kind: str) -> tuple[int, bytes]:
    """(unit id, PDU) a flooding client repeats: drive 1's own set-point written again (the
    readers' values stay right), or a broadcast stop."""
    if kind == "broadcasts":
        return 0, STOP_COMMAND
    return 1, struct.pack(">BHH", 6, 0x2001, 1100)  # what the bench set drive 1's to


async def flood(port: int, kind: str, window: int, stop: asyncio.Event) -> int:
    """One client keeping `window` requests in flight until `stop`; the answers it got."""
    unit, pdu = flood_request(kind)
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    answered = 0
    frame = struct.pack(">HHHB", 0, 0, len(pdu) + 1, unit) + pdu
    try:
        for _ in range(window):
            writer.write(frame)
        while not stop.is_set():
            header = await reader.readexactly(7)
            await reader.readexactly(struct.unpack(">H", header[4:6])[0] - 1)
            answered += 1
            writer.write(frame)  # one answered, one more in flight
    finally:
        writer.close()
        with contextlib.suppress(Exception):
            await writer.wait_closed()
    return answered
