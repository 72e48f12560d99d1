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

import time
from collections import deque
from collections.abc import Callable
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
    moment the reply is there (`gateway.tcp.connection`'s `_Answer`) without a task to wake."""

    def done(self) -> bool: ...

    def set_result(self, result: bytes | None, /) -> None: ...

    def set_exception(self, exception: BaseException, /) -> None: ...


class RequestReport(Protocol):
    """Who is told of a caller's request answered (`gateway.bus.observers.BusObservers`)."""

    def report(
        self,
        address: int,
        pdu: bytes,
        client: str,
        started: float,
        reply: bytes | None,
        code: int | None = None,
    ) -> None: ...


class Priority(IntEnum):
    WRITE = 0
    READ = 1
    POLL = 2


class Transaction:
    """One request for the wire and everyone waiting for its reply.

    A plain class rather than a dataclass: one is made per request, and its `__init__` takes
    its fields by position (a keyword call costs a name match per argument) and works the
    coalescing key out once, where the queue reads it twice (`put`, `get_nowait`)."""

    __slots__ = (
        "address",
        "client",
        "coalescable",
        "frame",
        "key",
        "observed_by",
        "pdu",
        "priority",
        "probe",
        "queued_at",
        "retries",
        "timeout_s",
        "use",
        "waiters",
    )

    def __init__(
        self,
        address: int,
        pdu: bytes,
        priority: Priority,
        client: str,
        timeout_s: float,
        retries: int,
        coalescable: bool = False,
        waiters: list[Waiter] | None = None,
        probe: bool = False,
        frame: bytes = b"",
        queued_at: float = 0.0,
        observed_by: RequestReport | None = None,
    ) -> None:
        self.address = address
        self.pdu = pdu
        self.priority = priority
        self.client = client
        self.timeout_s = timeout_s
        self.retries = retries
        self.coalescable = coalescable
        self.waiters: list[Waiter] = [] if waiters is None else waiters
        self.probe = probe
        """A bus's own check of an offline drive: nobody waits for it, it is always wanted."""
        self.frame = frame
        """The RTU frame, built when queued: CRC work done while the line is busy, not in the
        gap."""
        self.queued_at = queued_at
        """When it was queued (`time.monotonic()`): did it wait for the gap, or the gap for
        it?"""
        self.use = _OTHER_USE
        """The share of the line its time is charged to (`RequestQueue.put` sets it)."""
        self.key: tuple[int, bytes, Priority] = (address, pdu, priority)
        """What identical reads share (`RequestQueue`): address, request PDU, priority."""
        self.observed_by = observed_by
        """Who is told of the outcome of `waiters[0]` (its own waiter), with its exception code
        or None, before that waiter is given it, unless that waiter is done by then: the bus's
        request observers, timed from `queued_at`. None: nobody (or the waiter is wrapped to
        tell them itself). Carried here rather than by a wrapper object around the waiter:
        one object less per request. A waiter added by coalescing brings its own wrapper."""

    def __repr__(self) -> str:
        return (
            f"Transaction(address={self.address}, pdu={self.pdu.hex()}, "
            f"priority={self.priority.name}, client={self.client!r}, "
            f"waiters={len(self.waiters)}, probe={self.probe})"
        )

    def wanted(self) -> bool:
        """False once every waiter has gone (client disconnected): no bus time for it then.
        A method, not a property: asked once per transaction, and Python 3.11 specialises a
        method's call, not a property's read (a generic lookup and a descriptor call)."""
        if self.probe:
            return True
        # A loop, not any(): no generator frame per transaction.
        for waiter in self.waiters:  # noqa: SIM110
            if not waiter.done():
                return True
        return False


# Members of the enums above read per transaction, as module globals. On Python 3.11 an enum
# class's metaclass defines `__getattr__`, which sends every `Priority.WRITE` through a slow
# attribute lookup: about 950 instructions a read against 45 for a global (callgrind).
_WRITE, _POLL = Priority.WRITE, Priority.POLL
_OTHER_USE, _BROADCAST_USE = LineUse.OTHER, LineUse.BROADCAST
USE_OF_PRIORITY = {
    Priority.WRITE: LineUse.WRITE,
    Priority.READ: _OTHER_USE,
    Priority.POLL: LineUse.POLL,
}
"""The share a transaction of each priority is charged to; broadcasts apart. A dict: Python
3.11 specialises a dict's subscript, not a tuple's by an IntEnum (a generic lookup each time)."""


class RequestQueue:
    """Not thread-safe by itself: the bus holds its lock around every call."""

    def __init__(self, maxsize: int, shares: LineShares | None = None) -> None:
        self.maxsize = maxsize
        # priority -> client -> that client's transactions; dicts keep insertion order, and a
        # client served goes to the back, which is the round robin.
        self._levels: dict[Priority, dict[str, deque[Transaction]]] = {p: {} for p in Priority}
        self._reads = self._levels[Priority.READ]
        self._polls = self._levels[Priority.POLL]
        """Two levels by name (the same dicts, never replaced): looked at per transaction."""
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
        self._spare: deque[Transaction] | None = None
        """A client's deque emptied by `get_nowait`, for the next client `put` finds with
        none: a client that asks one at a time would otherwise make and drop one per request
        (a deque's block is a C allocation of its own)."""
        self._reads_while_polls_wait = 0
        self._read_since_poll: set[str] = set()
        """Clients served a read since the last poll, while polls waited."""
        self.coalesced = 0

    def __len__(self) -> int:
        return self._size

    @property
    def reads_waiting(self) -> bool:
        """Client reads wait for the line: a poll that goes now holds them up for its time."""
        return bool(self._reads)

    def put(self, transaction: Transaction) -> Transaction:
        """Queue `transaction`, or attach its waiters to an identical queued read.

        Returns the transaction that will carry the request. Raises QueueFull.
        """
        coalescable = transaction.coalescable
        if coalescable:
            queued = self._coalescing.get(transaction.key)
            if queued is not None:
                queued.waiters.extend(transaction.waiters)
                self.coalesced += 1
                return queued
        if self._size >= self.maxsize:
            raise QueueFull(f"bus queue full ({self.maxsize} requests waiting)")
        priority = transaction.priority
        # Broadcasts wait apart from the other writes, and are charged apart (their own share).
        if priority is _WRITE and transaction.address == BROADCAST:
            clients = self._broadcasts
            transaction.use = _BROADCAST_USE
        else:
            clients = self._levels[priority]
            transaction.use = USE_OF_PRIORITY[priority]
        client = transaction.client
        waiting = clients.get(client)
        if waiting is None:
            waiting = self._spare
            if waiting is None:
                clients[client] = deque((transaction,))
            else:
                self._spare = None
                waiting.append(transaction)
                clients[client] = waiting
        else:
            waiting.append(transaction)
        if coalescable:
            self._coalescing[transaction.key] = transaction
        self._alone = None if self._size else clients
        self._size += 1
        return transaction

    def charge(self, transaction: Transaction, seconds: float, now: float) -> None:
        """`transaction` held the line for `seconds`: count it against its kind's share."""
        self._meter.charge(transaction.use, seconds, now)

    @property
    def charge_share(self) -> Callable[[LineUse, float, float], None]:
        """The line-time meter's own `charge`, bound once by the bus for `charge`'s work
        without its call (once per transaction): given a transaction's `use`."""
        return self._meter.charge

    def get_nowait(self, now: float | None = None) -> Transaction | None:
        """The next transaction to serve; `now` (monotonic, read here if not given) for the
        line-time shares."""
        clients = self._alone
        reads, polls = self._reads, self._polls
        if clients is not None:
            # The only one waiting: what the rules would choose, with what choosing a read or a
            # poll alone does to the polls' turn (nothing waits behind it to take turns with).
            self._alone = None
            if clients is reads or clients is polls:
                self._reads_while_polls_wait = 0
                if self._read_since_poll:
                    self._read_since_poll.clear()
        else:
            clients = self._next_clients(time.monotonic() if now is None else now)
            if clients is None:
                return None
        client = next(iter(clients))  # the front of the round robin (no items view, no pair)
        waiting = clients[client]
        if clients is polls:
            self._read_since_poll.clear()
        elif polls and clients is reads:
            self._read_since_poll.add(client)
        transaction = waiting.popleft()
        del clients[client]
        if waiting:
            clients[client] = waiting  # back of the round robin
        else:
            self._spare = waiting
        self._size -= 1
        if transaction.coalescable:
            key = transaction.key
            coalescing = self._coalescing
            if coalescing.get(key) is transaction:
                del coalescing[key]
        return transaction

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
