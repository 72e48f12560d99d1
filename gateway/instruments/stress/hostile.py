"""A hostile Modbus-TCP client: random and mutated MBAP frames, malformed headers, frames cut in
pieces, on connection after connection, while the checked clients work.

It addresses unit ids no drive has, so its frames cost the line nothing and can change no drive:
what it tests is the gateway's framing. Every answer it gets must be to a frame it sent (same
transaction id and unit id); a malformed header must end the connection.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import random
import struct
from collections import Counter
from dataclasses import dataclass, field
from typing import Final

UNIT_IDS: Final = range(200, 248)
"""Unit ids the stress run gives no drive."""
PAUSE_S: Final = 0.02
"""Between bursts: hostile, not a denial of service on our own test machine."""
READ_TIMEOUT_S: Final = 2.0


@dataclass
class HostileStats:
    frames: int = 0
    malformed: int = 0
    """Frames sent with a header no Modbus client can mean (protocol id ≠ 0, bad length)."""
    connections: int = 0
    closed_by_gateway: int = 0
    answers: int = 0
    wrong: int = 0
    """Answers to nothing it sent, or a malformed header the gateway let pass."""
    examples: list[str] = field(default_factory=list)


class HostileClient:
    def __init__(self, port: int, seed: int, host: str = "127.0.0.1") -> None:
        self.host = host
        self.port = port
        self.stats = HostileStats()
        self._rng = random.Random(seed)
        self.kills = 0
        """Counted up as a kill of the gateway begins and again once its process is gone (odd
        while one is under way): a connection open at a kill, or opened while the process was
        being killed, is closed by the kill, not by the gateway."""

    async def run(self, stop: asyncio.Event) -> None:
        while not stop.is_set():
            with contextlib.suppress(OSError, asyncio.IncompleteReadError, TimeoutError):
                await self._one_connection()
            await asyncio.sleep(PAUSE_S)

    async def _one_connection(self) -> None:
        kills = self.kills
        reader, writer = await asyncio.open_connection(self.host, self.port)
        self.stats.connections += 1
        try:
            stream, due, malformed = self._burst()
            for piece in self._pieces(stream):
                writer.write(piece)
                await writer.drain()
            await self._collect(reader, due, malformed, kills)
        finally:
            writer.close()
            with contextlib.suppress(Exception):
                await writer.wait_closed()

    def _burst(self) -> tuple[bytes, Counter[tuple[int, int]], bool]:
        """Frames, the (transaction id, unit id) each must be answered with, and whether a
        malformed header ends the burst."""
        rng = self._rng
        stream = bytearray()
        due: Counter[tuple[int, int]] = Counter()
        for _ in range(rng.randint(1, 12)):
            tid, unit = rng.randrange(0x10000), rng.choice(UNIT_IDS)
            pdu = rng.randbytes(rng.randint(1, 30))
            stream += struct.pack(">HHHB", tid, 0, len(pdu) + 1, unit) + pdu
            due[(tid, unit)] += 1
            self.stats.frames += 1
        malformed = rng.random() < 0.3
        if malformed:
            protocol, length = rng.choice(
                [
                    (rng.randint(1, 0xFFFF), 6),
                    (0, rng.choice([0, 1])),
                    (0, rng.randint(255, 0xFFFF)),
                ]
            )
            stream += struct.pack(">HHHB", rng.randrange(0x10000), protocol, length, 200)
            stream += rng.randbytes(rng.randint(0, 20))
            self.stats.frames += 1
            self.stats.malformed += 1
        return bytes(stream), due, malformed

    def _pieces(self, stream: bytes) -> list[bytes]:
        cuts = sorted(self._rng.sample(range(1, len(stream)), k=min(3, len(stream) - 1)))
        return [stream[a:b] for a, b in itertools.pairwise([0, *cuts, len(stream)])]

    async def _collect(
        self,
        reader: asyncio.StreamReader,
        due: Counter[tuple[int, int]],
        malformed: bool,
        kills: int,
    ) -> None:
        while malformed or due.total():
            try:
                header = await asyncio.wait_for(reader.read(7), READ_TIMEOUT_S)
            except TimeoutError:  # the gateway is there (else: reset), but silent
                self._wrong(
                    "a malformed header left the connection open"
                    if malformed
                    else "frames left unanswered"
                )
                return
            if not header:
                self.stats.closed_by_gateway += 1
                if not malformed and self.kills == kills and not kills % 2:  # no SIGKILL of ours
                    self._wrong("closed a connection that sent nothing malformed")
                return
            header += await asyncio.wait_for(reader.readexactly(7 - len(header)), READ_TIMEOUT_S)
            tid, _, length, unit = struct.unpack(">HHHB", header)
            await asyncio.wait_for(reader.readexactly(length - 1), READ_TIMEOUT_S)
            self.stats.answers += 1
            if due[(tid, unit)] <= 0:
                self._wrong(f"an answer to nothing sent: transaction {tid}, unit {unit}")
                return
            due[(tid, unit)] -= 1

    def _wrong(self, what: str) -> None:
        self.stats.wrong += 1
        if len(self.stats.examples) < 5:
            self.stats.examples.append(what)
