"""What a case does before its measured time: each drive's own set-points written, and the
answer to every read its clients will ask learnt."""

from __future__ import annotations

import asyncio
import struct
from typing import Protocol

from gateway.instruments.bench.load import Target

SET_POINT = 0x2001  # 2001H..2008H: set-points and limits, written per drive (set_point_values)
RUNNING_VALUES = 0x3000  # 3000H..: running values; static while the drives stand still
READS_PER_DRIVE = 8
"""Different reads the clients of one drive make (a start address each: 2001H-2008H for 2
words, 3000H-3007H for 16): no two clients ask the same, so none joins another's transaction."""


def set_point_values(address: int) -> tuple[int, ...]:
    """What the bench writes to 2001H-2008H of the drive at `address`: a value of its own in
    each register every read covers (3008H, 3009H and 3015H mirror 2002H-2004H), within each
    register's limits, so a reply from another drive or of another read is caught as wrong.
    Frequency set-point, PID reference and feedback, torque set-point, the two frequency
    limits (below P00.03's 50 Hz), the two torque limits."""
    a = address
    return (1000 + 100 * a, 10 * a, 20 * a, 30 * a, 4000 + a, 4000 + 2 * a, 1500 + a, 1500 + 2 * a)


class ReadCase(Protocol):
    """What `prepare_reads` needs of a case (`cases.Case`)."""

    @property
    def name(self) -> str: ...
    @property
    def words(self) -> int: ...
    @property
    def clients(self) -> int: ...
    @property
    def drives(self) -> int: ...
    @property
    def same_registers(self) -> bool: ...
    def units(self, line: int) -> list[int]: ...


async def prepare_reads(case: ReadCase, port: int, dead: list[int], line: int = 0) -> list[Target]:
    """Give each drive its own set-points, then learn the right answer to every read: the one
    each of the line's clients asks, client by client.

    Each client asks one drive one read of its own, so every request is a transaction of its
    own and the clients contend for the line. Clients whose reads were alike would share a
    transaction, be answered together, ask again together and, a few transactions on, all be
    in step: one transaction per round for all of them and nothing waiting between rounds (the
    line would measure the coalescing, not the contention). `same_registers`: every client
    asks drive 1 the same read, which is the coalescing case.
    """
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    tid = 0

    async def request(unit: int, pdu: bytes) -> bytes:
        nonlocal tid
        tid += 1
        writer.write(struct.pack(">HHHB", tid, 0, len(pdu) + 1, unit) + pdu)
        _, _, length, _ = struct.unpack(">HHHB", await reader.readexactly(7))
        return await reader.readexactly(length - 1)

    start = SET_POINT if case.words <= 2 else RUNNING_VALUES
    on_line = case.units(line)
    units = on_line[:1] if case.same_registers else on_line
    slots = 1 if case.same_registers else -(-case.clients // len(units))
    if slots > READS_PER_DRIVE:
        raise ValueError(f"{case.name}: more than {READS_PER_DRIVE} clients per drive")
    targets: dict[tuple[int, int], Target] = {}
    for unit in units:
        address = unit - line * case.drives
        if address not in dead:
            set_points = struct.pack(">BHHB", 0x10, SET_POINT, 8, 16) + struct.pack(
                ">8H", *set_point_values(address)
            )
            reply = await request(unit, set_points)
            if reply[0] != 0x10:
                raise RuntimeError(f"drive {unit} refused its set-points: {reply.hex(' ')}")
        for slot in range(slots):
            pdu = struct.pack(">BHH", 3, start + slot, case.words)
            if address in dead:
                targets[unit, slot] = Target(unit, pdu, b"")
                continue
            expected = await request(unit, pdu)
            if expected[0] != 3:
                raise RuntimeError(f"drive {unit} refused the benchmark read: {expected.hex(' ')}")
            targets[unit, slot] = Target(unit, pdu, expected)
    writer.close()
    await writer.wait_closed()
    # Client n: the n-th drive (in turn), the read numbered by how many went round before it
    # (`same_registers`: one drive, one read, for every client).
    return [targets[units[n % len(units)], n // len(units) % slots] for n in range(case.clients)]
