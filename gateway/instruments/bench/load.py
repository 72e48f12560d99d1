"""Modbus-TCP clients for the benchmark: one request outstanding each, every reply checked."""

from __future__ import annotations

import asyncio
import contextlib
import struct
import time
from collections import Counter
from dataclasses import dataclass, field

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
    await asyncio.gather(
        *(
            _client(port, target, dead_units, measuring, stop, result, dead_pause_s)
            for target in reads
        )
    )
    return result


async def _client(
    port: int,
    target: Target,
    dead_units: frozenset[int],
    measuring: asyncio.Event,
    stop: asyncio.Event,
    result: LoadResult,
    dead_pause_s: float,
) -> None:
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    tid = 0
    try:
        while not stop.is_set():
            tid = (tid + 1) & 0xFFFF
            header = struct.pack(">HHHB", tid, 0, len(target.pdu) + 1, target.unit_id)
            started = time.perf_counter()
            writer.write(header + target.pdu)
            reply_header = await reader.readexactly(7)
            reply_tid, _, length, unit = struct.unpack(">HHHB", reply_header)
            pdu = await reader.readexactly(length - 1)
            latency = time.perf_counter() - started
            if dead_pause_s and target.unit_id in dead_units:
                await asyncio.sleep(dead_pause_s)
            if not measuring.is_set():
                continue
            if reply_tid != tid or unit != target.unit_id:
                result.wrong += 1
            elif target.unit_id in dead_units:
                result.dead_answers += pdu == DEAD_DRIVE_REPLY
                result.wrong += pdu != DEAD_DRIVE_REPLY
            elif pdu == target.expected:
                result.answered += 1
                result.answered_by_unit[unit] += 1
                result.latencies_s.append(latency)
            elif pdu[0] & 0x80:
                result.errors += 1
            else:
                result.wrong += 1
    finally:
        writer.close()
        with contextlib.suppress(Exception):
            await writer.wait_closed()


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
