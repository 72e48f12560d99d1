"""The bus's queue: bounded, by priority, fair between clients, coalescing identical reads.

Order of service:
1. priority: writes first (a stop command never waits behind polls), then client reads, then polls,
   except that polls get a turn while reads are waiting too (telemetry and dead-drive probes must
   not starve under a SCADA that reads without pause): one in `POLL_SHARE` at most, while their
   time on the line is under `poll_share` of it (`gateway.bus.line_share`: every second a full
   line gives polls is one its readers wait), and only once every client waiting to read has
   had a read since the last poll, so that a poll holds a waiting client for one poll
   transaction at most; and writes take at most their share of the line's time while reads
   wait, broadcasts theirs while anything else waits: one client's flood of writes can't
   freeze the others' reads;
2. within a priority, round-robin between clients (one busy SCADA can't starve another);
3. within a client, first come first served.

An identical read (same address, same request PDU, same priority) that is still waiting is not
queued twice: the new caller waits on the transaction already queued, and one bus transaction
answers both. Reads only: writing twice is not the same as writing once.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Protocol

from gateway.bus.line_share import LineShares, LineUse, ShareMeter
from gateway.errors import QueueFull

BROADCAST = 0
"""Address 0: every drive, no reply."""
POLL_SHARE = 4
"""While reads and polls both wait, one transaction in this many at most goes to a poll."""


class Waiter(Protocol):
    """Who waits for a transaction's reply: an asyncio future, or an answer that goes out the
    moment the reply is there (`gateway.tcp.server`'s fast path) without a task to wake."""

    def done(self) -> bool: ...

    def set_result(self, result: bytes | None, /) -> None: ...

    def set_exception(self, exception: BaseException, /) -> None: ...


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
    waiters: list[Waiter] = field(default_factory=list)
    probe: bool = False
    """A bus's own check of an offline drive: nobody waits for it, it is always wanted."""
    frame: bytes = b""
    """The RTU frame, built when queued: CRC work done while the line is busy, not in the gap."""
    queued_at: float = 0.0
    """When it was queued (`time.monotonic()`): did it wait for the gap, or the gap for it?"""

    @property
    def key(self) -> tuple[int, bytes, Priority]:
        return (self.address, self.pdu, self.priority)

    @property
    def wanted(self) -> bool:
        """False once every waiter has gone (client disconnected): no bus time for it then."""
        if self.probe:
            return True
        # A loop, not any(): no generator frame per transaction.
        for waiter in self.waiters:  # noqa: SIM110
            if not waiter.done():
                return True
        return False


_USES = {Priority.WRITE: LineUse.WRITE, Priority.READ: LineUse.OTHER, Priority.POLL: LineUse.POLL}
"""The kind of line time a transaction of each priority takes (a broadcast's is its own)."""


class RequestQueue:
    """Not thread-safe by itself: the bus holds its lock around every call."""

    def __init__(self, maxsize: int, shares: LineShares | None = None) -> None:
        self.maxsize = maxsize
        # priority -> client -> that client's transactions; dicts keep insertion order, and a
        # client served goes to the back, which is the round robin.
        self._levels: dict[Priority, dict[str, deque[Transaction]]] = {p: {} for p in Priority}
        # Broadcasts (address 0) wait apart from the other writes: they have a share of their own.
        self._broadcasts: dict[str, deque[Transaction]] = {}
        self._meter = ShareMeter(shares or LineShares())
        self._coalescing: dict[tuple[int, bytes, Priority], Transaction] = {}
        self._size = 0
        self._alone: dict[str, deque[Transaction]] | None = None
        """Where the one transaction waiting is, when it was queued into an empty queue and is
        still the only one; else None. It goes next whatever the rules (a share is for sharing,
        not for idling): `get_nowait` takes it without weighing the levels, as it does once per
        transaction on a line whose clients ask one at a time."""
        self._reads_while_polls_wait = 0
        self._read_since_poll: set[str] = set()
        """Clients served a read since the last poll, while polls waited."""
        self.coalesced = 0

    def __len__(self) -> int:
        return self._size

    def put(self, transaction: Transaction) -> Transaction:
        """Queue `transaction`, or attach its waiters to an identical queued read.

        Returns the transaction that will carry the request. Raises QueueFull.
        """
        key = transaction.key if transaction.coalescable else None
        if key is not None:
            queued = self._coalescing.get(key)
            if queued is not None:
                queued.waiters.extend(transaction.waiters)
                self.coalesced += 1
                return queued
        if self._size >= self.maxsize:
            raise QueueFull(f"bus queue full ({self.maxsize} requests waiting)")
        clients = self._clients_of(transaction)
        clients.setdefault(transaction.client, deque()).append(transaction)
        if key is not None:
            self._coalescing[key] = transaction
        self._alone = clients if not self._size else None
        self._size += 1
        return transaction

    def charge(self, transaction: Transaction, seconds: float, now: float) -> None:
        """`transaction` held the line for `seconds`: count it against its kind's share."""
        use = LineUse.BROADCAST if transaction.address == BROADCAST else _USES[transaction.priority]
        self._meter.charge(use, seconds, now)

    def get_nowait(self, now: float = 0.0) -> Transaction | None:
        """The next transaction to serve; `now` (monotonic) for the line-time shares."""
        levels = self._levels
        clients = self._alone
        if clients is not None:
            # The only one waiting: what the rules would choose, with what choosing a read or a
            # poll alone does to the polls' turn (nothing waits behind it to take turns with).
            self._alone = None
            if clients is levels[Priority.READ] or clients is levels[Priority.POLL]:
                self._reads_while_polls_wait = 0
                self._read_since_poll.clear()
        else:
            clients = self._next_clients(now)
            if clients is None:
                return None
        client, waiting = next(iter(clients.items()))
        if clients is levels[Priority.POLL]:
            self._read_since_poll.clear()
        elif levels[Priority.POLL] and clients is levels[Priority.READ]:
            self._read_since_poll.add(client)
        transaction = waiting.popleft()
        del clients[client]
        if waiting:
            clients[client] = waiting  # back of the round robin
        self._size -= 1
        if transaction.coalescable:
            key = transaction.key
            if self._coalescing.get(key) is transaction:
                del self._coalescing[key]
        return transaction

    def _clients_of(self, transaction: Transaction) -> dict[str, deque[Transaction]]:
        if transaction.address == BROADCAST and transaction.priority is Priority.WRITE:
            return self._broadcasts
        return self._levels[transaction.priority]

    def _next_clients(self, now: float) -> dict[str, deque[Transaction]] | None:
        """Broadcasts and writes first, each within its share of the line while others wait."""
        levels = self._levels
        reads_wait = bool(levels[Priority.READ] or levels[Priority.POLL])
        if self._broadcasts and (
            not (reads_wait or levels[Priority.WRITE]) or self._meter.broadcasts_may_go(now)
        ):
            return self._broadcasts
        if levels[Priority.WRITE] and (not reads_wait or self._meter.writes_may_go(now)):
            return levels[Priority.WRITE]
        level = self._next_level(now)
        if level is not None:
            return levels[level]
        # Only writes wait, over their share: the share is for sharing, not for idling.
        return self._broadcasts or None

    def _next_level(self, now: float) -> Priority | None:
        """Reads, then polls; but polls get a turn while reads wait, so telemetry never stops
        under a SCADA that reads without pause: after POLL_SHARE - 1 reads, within their share
        of the line's time, once every client waiting to read has had a read since the last
        poll (no waiting client held by two polls)."""
        levels = self._levels
        reads = levels[Priority.READ]
        if not levels[Priority.POLL]:
            self._reads_while_polls_wait = 0
            self._read_since_poll.clear()
            return Priority.READ if reads else None
        if not reads or (
            self._reads_while_polls_wait >= POLL_SHARE - 1
            and self._read_since_poll.issuperset(reads)
            and self._meter.polls_may_go(now)
        ):
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
