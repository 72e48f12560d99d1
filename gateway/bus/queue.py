"""The bus's queue: bounded, by priority, fair between clients, coalescing identical reads.

Order of service:
1. priority: writes first (a stop command never waits behind polls), then client reads, then polls,
   except that polls get one turn in `POLL_SHARE` while reads are waiting too (telemetry and
   dead-drive probes must not starve under a SCADA that reads without pause);
2. within a priority, round-robin between clients (one busy SCADA can't starve another);
3. within a client, first come first served.

An identical read (same address, same request PDU, same priority) that is still waiting is not
queued twice: the new caller waits on the transaction already queued, and one bus transaction
answers both. Reads only: writing twice is not the same as writing once.
"""

from __future__ import annotations

import asyncio
from collections import deque
from dataclasses import dataclass, field
from enum import IntEnum

from gateway.errors import QueueFull

POLL_SHARE = 4
"""While reads and polls both wait, one transaction in this many goes to a poll."""


class Priority(IntEnum):
    WRITE = 0
    READ = 1
    POLL = 2


@dataclass(eq=False, slots=True)
class Transaction:
    """One request for the wire and everyone waiting for its reply."""

    address: int
    pdu: bytes
    priority: Priority
    client: str
    timeout_s: float
    retries: int
    coalescable: bool = False
    waiters: list[asyncio.Future[bytes | None]] = field(default_factory=list)
    probe: bool = False
    """A bus's own check of an offline drive: nobody waits for it, it is always wanted."""
    frame: bytes = b""
    """The RTU frame, built when queued: CRC work done while the line is busy, not in the gap."""

    @property
    def key(self) -> tuple[int, bytes, Priority]:
        return (self.address, self.pdu, self.priority)

    @property
    def wanted(self) -> bool:
        """False once every waiter has gone (client disconnected): no bus time for it then."""
        return self.probe or any(not waiter.done() for waiter in self.waiters)


class RequestQueue:
    """Not thread-safe by itself: the bus holds its lock around every call."""

    def __init__(self, maxsize: int) -> None:
        self.maxsize = maxsize
        # priority -> client -> that client's transactions; dicts keep insertion order, and a
        # client served goes to the back, which is the round robin.
        self._levels: dict[Priority, dict[str, deque[Transaction]]] = {p: {} for p in Priority}
        self._coalescing: dict[tuple[int, bytes, Priority], Transaction] = {}
        self._size = 0
        self._reads_while_polls_wait = 0
        self.coalesced = 0

    def __len__(self) -> int:
        return self._size

    def put(self, transaction: Transaction) -> Transaction:
        """Queue `transaction`, or attach its waiters to an identical queued read.

        Returns the transaction that will carry the request. Raises QueueFull.
        """
        if transaction.coalescable:
            queued = self._coalescing.get(transaction.key)
            if queued is not None:
                queued.waiters.extend(transaction.waiters)
                self.coalesced += 1
                return queued
        if self._size >= self.maxsize:
            raise QueueFull(f"bus queue full ({self.maxsize} requests waiting)")
        clients = self._levels[transaction.priority]
        clients.setdefault(transaction.client, deque()).append(transaction)
        if transaction.coalescable:
            self._coalescing[transaction.key] = transaction
        self._size += 1
        return transaction

    def get_nowait(self) -> Transaction | None:
        level = self._next_level()
        if level is None:
            return None
        clients = self._levels[level]
        client, waiting = next(iter(clients.items()))
        transaction = waiting.popleft()
        del clients[client]
        if waiting:
            clients[client] = waiting  # back of the round robin
        self._size -= 1
        if self._coalescing.get(transaction.key) is transaction:
            del self._coalescing[transaction.key]
        return transaction

    def _next_level(self) -> Priority | None:
        """Writes first, then reads; but polls get every POLL_SHARE-th turn while reads wait,
        so telemetry never stops under a SCADA that reads without pause."""
        levels = self._levels
        if levels[Priority.WRITE]:
            return Priority.WRITE
        if not levels[Priority.POLL]:
            self._reads_while_polls_wait = 0
            return Priority.READ if levels[Priority.READ] else None
        if not levels[Priority.READ] or self._reads_while_polls_wait >= POLL_SHARE - 1:
            self._reads_while_polls_wait = 0
            return Priority.POLL
        self._reads_while_polls_wait += 1
        return Priority.READ

    def take_all(self) -> list[Transaction]:
        """Empty the queue (shutdown, port lost): the caller answers every waiter."""
        taken: list[Transaction] = []
        while (transaction := self.get_nowait()) is not None:
            taken.append(transaction)
        return taken
