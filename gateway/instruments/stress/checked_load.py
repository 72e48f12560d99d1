"""Modbus-TCP clients that check every value they receive against what the drive must hold.

Each client owns a block of parameters on one drive that no one else writes (P00.11-P00.12,
P08.07-P08.08 or P01.20 of its drive), writes new values to it now and then and reads it back
between writes, with a neighbour or two that nobody writes. So the client always knows the drive's
true value, and a reply that is stale (a late reply taken for the next one), from another drive
or mixed up with another client's is caught, not just a malformed one:

- an acknowledged write makes the written values the only right ones;
- a write that failed (0BH, connection lost) may or may not have reached the drive: the old and
  the new values are both right until a read tells which;
- a register nobody writes is learnt from its first read and must never change.

A client reconnects by itself when the gateway goes away, so the same load runs through a port
unplugged, a broker restarted, a gateway killed. Errors are counted per `phase` (steady, or the
outage the scenario is in), because errors during an outage are expected and elsewhere are not.
"""

from __future__ import annotations

import asyncio
import contextlib
import random
import struct
import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Final

from gateway.profile.addressing import parse_parameter

WRITE_SINGLE: Final = 0x06
WRITE_MULTIPLE: Final = 0x10
READ_HOLDING: Final = 0x03
MAX_VALUE: Final = 36000
"""The upper limit of every parameter in the blocks (acceleration times, 0.0-3600.0 s)."""
REPLY_TIMEOUT_S: Final = 5.0
"""Longer than the gateway's worst answer (0BH after every retry): silence this long is lost."""
RECONNECT_S: Final = 0.05
ERROR_PAUSE_S: Final = 0.01
"""After an exception answer, as a SCADA client's poll cycle would: not a tight loop of 0BH."""
WRITE_SHARE: Final = 0.3
STEADY: Final = "steady"


@dataclass(frozen=True, slots=True)
class Block:
    """Registers one client writes, inside a wider range it reads."""

    write_start: int
    write_count: int
    read_start: int
    read_count: int


# The first two read as many words: a late reply to one is byte for byte the shape of the
# other's, so only the values tell them apart (RTU has no transaction id), and they are checked.
BLOCKS: Final = (
    Block(parse_parameter("P00.11"), 2, parse_parameter("P00.10"), 3),  # P00.10 before
    Block(parse_parameter("P08.07"), 2, parse_parameter("P08.06"), 3),  # P08.06 before
    Block(parse_parameter("P01.20"), 1, parse_parameter("P01.20"), 1),
)


@dataclass
class LoadStats:
    requests: Counter[str] = field(default_factory=Counter)
    """Requests sent, per phase."""
    errors: Counter[str] = field(default_factory=Counter)
    """Requests without a right answer (an exception, a timeout, the connection lost), per phase."""
    exceptions: Counter[int] = field(default_factory=Counter)
    answered: int = 0
    checked_reads: int = 0
    """Reads answered with the values the drive truly holds (checked, not only well formed)."""
    wrong: int = 0
    """Answers that were there but not right: wrong values, transaction id, unit or function."""
    wrong_examples: list[str] = field(default_factory=list)
    last_ok_at: float = 0.0
    """monotonic() of the last right answer: the scenario's measure of recovery."""
    last_ok_by_unit: dict[int, float] = field(default_factory=dict)
    """Unit id → monotonic() of its last right answer."""
    last_ok_connected_at: float = 0.0
    """When the connection that answer came on was opened (after a gateway restart, answers
    still buffered on a connection to the dead process are no sign of recovery)."""

    def add_wrong(self, what: str) -> None:
        self.wrong += 1
        if len(self.wrong_examples) < 10:
            self.wrong_examples.append(what)


@dataclass(frozen=True, slots=True)
class Assignment:
    unit_id: int
    block: Block


def assignments(unit_ids: list[int], clients: int) -> list[Assignment]:
    """One block per client, spread over the drives first; at most 3 clients per drive."""
    if clients > len(unit_ids) * len(BLOCKS):
        raise ValueError(
            f"{clients} clients but only {len(unit_ids) * len(BLOCKS)} parameter blocks on "
            f"{len(unit_ids)} drives: each client needs a block no other client writes"
        )
    return [
        Assignment(unit_ids[i % len(unit_ids)], BLOCKS[i // len(unit_ids)]) for i in range(clients)
    ]


class CheckedLoad:
    """Clients on one gateway port; `phase` labels what their errors are counted under."""

    def __init__(
        self, port: int, unit_ids: list[int], clients: int, seed: int = 1, host: str = "127.0.0.1"
    ) -> None:
        self.host = host
        self.port = port
        self.stats = LoadStats()
        self.phase = STEADY
        self._stop = asyncio.Event()
        self._max_requests: int | None = None
        self.sent = 0
        self._clients = [
            _Client(self, assignment, random.Random(seed * 1000 + index))
            for index, assignment in enumerate(assignments(unit_ids, clients))
        ]

    async def run(self, stop: asyncio.Event, max_requests: int | None = None) -> None:
        """Until `stop` is set, or until `max_requests` have been sent in all."""
        self._max_requests = max_requests
        self._stop = stop
        await asyncio.gather(*(client.run() for client in self._clients))

    def beliefs(self) -> list[tuple[int, int, frozenset[int] | None]]:
        """(unit id, register, the values the drive may hold there: None when not known yet)."""
        return [
            (client.unit_id, register, possible)
            for client in self._clients
            for register, possible in client.expected.items()
        ]

    def may_send(self) -> bool:
        if self._stop.is_set():
            return False
        return self._max_requests is None or self.sent < self._max_requests


class _Client:
    def __init__(self, load: CheckedLoad, assignment: Assignment, rng: random.Random) -> None:
        self.load = load
        self.unit_id = assignment.unit_id
        self.block = assignment.block
        self.rng = rng
        self.expected: dict[int, frozenset[int] | None] = {
            register: None
            for register in range(
                self.block.read_start, self.block.read_start + self.block.read_count
            )
        }
        self.tid = rng.randrange(0x10000)
        self.written = False
        self.connected_at = 0.0

    async def run(self) -> None:
        while self.load.may_send():
            try:
                reader, writer = await asyncio.open_connection(self.load.host, self.load.port)
            except OSError:
                await asyncio.sleep(RECONNECT_S)
                continue
            self.connected_at = time.monotonic()
            try:
                while self.load.may_send():
                    await self._one_request(reader, writer)
            except (OSError, asyncio.IncompleteReadError, TimeoutError):
                await asyncio.sleep(RECONNECT_S)  # counted already; the gateway went away
            finally:
                writer.close()
                with contextlib.suppress(Exception):
                    await writer.wait_closed()

    async def _one_request(
        self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter
    ) -> None:
        writes = not self.written or self.rng.random() < WRITE_SHARE
        values = self._new_values() if writes else ()
        pdu = self._write_pdu(values) if writes else self._read_pdu()
        self.tid = (self.tid + 1) & 0xFFFF
        stats = self.load.stats
        sent_in = self.load.phase
        self.load.sent += 1  # before any await: `max_requests` is exact
        try:
            writer.write(struct.pack(">HHHB", self.tid, 0, len(pdu) + 1, self.unit_id) + pdu)
            reply = await asyncio.wait_for(self._receive(reader), REPLY_TIMEOUT_S)
        except (OSError, asyncio.IncompleteReadError, TimeoutError):
            phase = self._phase(sent_in)
            stats.requests[phase] += 1
            stats.errors[phase] += 1
            if writes:
                self._uncertain(values)
            raise
        phase = self._phase(sent_in)
        stats.requests[phase] += 1
        tid, unit_id, answer = reply
        if tid != self.tid or unit_id != self.unit_id or not answer or answer[0] & 0x7F != pdu[0]:
            stats.add_wrong(
                f"unit {self.unit_id} tid {self.tid}: got tid {tid} unit {unit_id} "
                f"{answer.hex(' ')} for {pdu.hex(' ')}"
            )
            raise ConnectionResetError("out of step with the gateway: reconnect")
        if answer[0] & 0x80:
            stats.errors[phase] += 1
            stats.exceptions[answer[1] if len(answer) > 1 else 0] += 1
            if writes:
                self._uncertain(values)
            await asyncio.sleep(ERROR_PAUSE_S)
            return
        if self._check(pdu, answer, values):
            stats.answered += 1
            if pdu[0] == READ_HOLDING:
                stats.checked_reads += 1
            stats.last_ok_at = stats.last_ok_by_unit[self.unit_id] = time.monotonic()
            stats.last_ok_connected_at = self.connected_at

    def _phase(self, sent_in: str) -> str:
        """A request that overlapped an outage belongs to it: the one sent just before the
        gateway was killed, as much as the one sent while it was down."""
        return sent_in if sent_in != STEADY else self.load.phase

    async def _receive(self, reader: asyncio.StreamReader) -> tuple[int, int, bytes]:
        header = await reader.readexactly(7)
        tid, _, length, unit_id = struct.unpack(">HHHB", header)
        return tid, unit_id, await reader.readexactly(max(length - 1, 0))

    def _new_values(self) -> tuple[int, ...]:
        return tuple(self.rng.randint(0, MAX_VALUE) for _ in range(self.block.write_count))

    def _write_pdu(self, values: tuple[int, ...]) -> bytes:
        start = self.block.write_start
        if len(values) == 1:
            return struct.pack(">BHH", WRITE_SINGLE, start, values[0])
        count = len(values)
        return struct.pack(f">BHHB{count}H", WRITE_MULTIPLE, start, count, 2 * count, *values)

    def _read_pdu(self) -> bytes:
        if self.rng.random() < 0.5:
            return struct.pack(">BHH", READ_HOLDING, self.block.read_start, self.block.read_count)
        return struct.pack(">BHH", READ_HOLDING, self.block.write_start, self.block.write_count)

    def _check(self, pdu: bytes, answer: bytes, values: tuple[int, ...]) -> bool:
        stats = self.load.stats
        if pdu[0] != READ_HOLDING:
            expected_echo = pdu if pdu[0] == WRITE_SINGLE else pdu[:5]
            if answer != expected_echo:
                stats.add_wrong(
                    f"unit {self.unit_id}: write {pdu.hex(' ')} answered {answer.hex(' ')}"
                )
                return False
            self.written = True
            for offset, value in enumerate(values):
                self.expected[self.block.write_start + offset] = frozenset({value})
            return True
        start, count = struct.unpack(">HH", pdu[1:5])
        if len(answer) != 2 + 2 * count or answer[1] != 2 * count:
            stats.add_wrong(f"unit {self.unit_id}: read of {count} answered {answer.hex(' ')}")
            return False
        words = struct.unpack(f">{count}H", answer[2:])
        right = True
        for register, value in zip(range(start, start + count), words, strict=True):
            possible = self.expected[register]
            if possible is not None and value not in possible:
                stats.add_wrong(
                    f"unit {self.unit_id} register {register:04X}H: {value}, the drive holds "
                    f"{sorted(possible)}"
                )
                right = False
            else:
                self.expected[register] = frozenset({value})
        return right

    def _uncertain(self, values: tuple[int, ...]) -> None:
        """A write whose fate is unknown: the drive holds the old values or the new."""
        for offset, value in enumerate(values):
            register = self.block.write_start + offset
            before = self.expected[register]
            self.expected[register] = None if before is None else before | {value}
