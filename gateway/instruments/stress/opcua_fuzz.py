"""A hostile OPC UA client: random and malformed OPC UA binary messages to the endpoint, for
`invt-gateway stress --opcua-fuzz N` and the tests.

Each message is one of: random bytes; a Hello (HEL) with random sizes, versions and endpoint
URLs (empty, huge, a negative length); a header that claims a message far larger than it sends
(oversized); a Hello cut short; a valid Hello then a random OpenSecureChannel (OPN), message
(MSG) or close (CLO) body; a chunk type that does not exist. They go 1 to 4 on a connection,
whose answers are read and counted: an Acknowledge (ACK), an Error (ERR), the connection closed
by the server. What the run must leave is the gateway serving its other doors and no
traceback in its log (the test and the stress case check both).
"""

from __future__ import annotations

import asyncio
import contextlib
import random
import struct
from collections import Counter
from dataclasses import dataclass, field
from typing import Final

READ_TIMEOUT_S: Final = 0.1
PAUSE_S: Final = 0.002
"""Between connections: hostile, not a denial of service on our own test machine."""
TYPES: Final = (b"HEL", b"ACK", b"ERR", b"OPN", b"MSG", b"CLO", b"RHE", b"XYZ")


@dataclass
class FuzzStats:
    messages: int = 0
    connections: int = 0
    answers: Counter[str] = field(default_factory=Counter)
    """What the server said: ACK, ERR, another type's name, `closed`, `silent`."""
    refused: int = 0
    """Connections the server did not take (its `max_connections` reached, or not listening)."""


def _string(text: bytes) -> bytes:
    return struct.pack("<i", len(text)) + text


def hello(endpoint: str, rng: random.Random | None = None) -> bytes:
    """A Hello; with `rng`, its numbers and URL drawn at random."""
    url = endpoint.encode()
    sizes = [0, 65535, 65535, 0, 0]
    if rng is not None:
        sizes = [rng.choice((0, 1, 8, 8192, 65535, 0xFFFFFFFF, rng.getrandbits(32))) for _ in sizes]
        url = rng.choice((b"", url, url * 200, bytes(rng.getrandbits(8) for _ in range(40))))
    body = struct.pack("<5I", *sizes) + _string(url)
    if rng is not None and rng.random() < 0.2:
        body = struct.pack("<5I", *sizes) + struct.pack("<i", rng.choice((-2, 0x7FFFFFFF)))
    return b"HELF" + struct.pack("<I", 8 + len(body)) + body


class OpcUaFuzzer:
    def __init__(self, host: str, port: int, seed: int) -> None:
        self.host = host
        self.port = port
        self.endpoint = f"opc.tcp://{host}:{port}/invt-gateway"
        self.stats = FuzzStats()
        self._rng = random.Random(seed)

    async def run(self, messages: int) -> FuzzStats:
        while self.stats.messages < messages:
            count = min(self._rng.randint(1, 4), messages - self.stats.messages)
            try:
                await self._one_connection(count)
            except OSError:
                self.stats.refused += 1
                self.stats.messages += count  # counted: they were meant for a refused door
            await asyncio.sleep(PAUSE_S)
        return self.stats

    async def _one_connection(self, count: int) -> None:
        reader, writer = await asyncio.open_connection(self.host, self.port)
        self.stats.connections += 1
        try:
            for _ in range(count):
                writer.write(self.message())
                self.stats.messages += 1
                with contextlib.suppress(OSError):
                    await writer.drain()
                said = await self._answer(reader)
                self.stats.answers[said] += 1
                if said == "closed":
                    return
        finally:
            writer.close()
            with contextlib.suppress(OSError):
                await writer.wait_closed()

    async def _answer(self, reader: asyncio.StreamReader) -> str:
        try:
            header = await asyncio.wait_for(reader.readexactly(8), READ_TIMEOUT_S)
        except TimeoutError:
            return "silent"
        except (asyncio.IncompleteReadError, OSError):
            return "closed"
        (size,) = struct.unpack("<I", header[4:8])
        with contextlib.suppress(TimeoutError, asyncio.IncompleteReadError, OSError):
            await asyncio.wait_for(reader.readexactly(max(0, min(size, 1 << 20) - 8)), 1.0)
        return header[:3].decode("ascii", "replace")

    async def hello_answer(self) -> str:
        """What a well-formed Hello gets (ACK from a server in good health)."""
        reader, writer = await asyncio.open_connection(self.host, self.port)
        try:
            writer.write(hello(self.endpoint))
            return await self._answer(reader)
        finally:
            writer.close()

    def message(self) -> bytes:
        rng = self._rng
        kind = rng.randrange(7)
        if kind == 0:
            return bytes(rng.getrandbits(8) for _ in range(rng.randint(1, 600)))
        if kind == 1:
            return hello(self.endpoint, rng)
        if kind == 2:  # oversized: claims up to 2 GB, sends a little
            claimed = rng.choice((1 << 24, 1 << 30, 0x7FFFFFFF, 0xFFFFFFFF))
            return rng.choice(TYPES) + b"F" + struct.pack("<I", claimed) + b"\x00" * 64
        if kind == 3:  # a Hello cut short
            whole = hello(self.endpoint)
            return whole[: rng.randint(1, len(whole) - 1)]
        if kind == 4:  # a chunk type that does not exist
            body = bytes(rng.getrandbits(8) for _ in range(rng.randint(0, 64)))
            return rng.choice(TYPES) + b"Q" + struct.pack("<I", 8 + len(body)) + body
        body = bytes(rng.getrandbits(8) for _ in range(rng.randint(0, 300)))
        kind_name = rng.choice((b"OPN", b"MSG", b"CLO"))
        chunk = kind_name + b"F" + struct.pack("<I", 8 + len(body)) + body
        return hello(self.endpoint) + chunk  # a valid Hello, then garbage on its channel


def summary(stats: FuzzStats) -> str:
    said = ", ".join(f"{name} {count}" for name, count in sorted(stats.answers.items()))
    return (
        f"OPC UA fuzz: {stats.messages} messages on {stats.connections} connections "
        f"({stats.refused} refused); the server answered: {said or 'nothing'}"
    )
