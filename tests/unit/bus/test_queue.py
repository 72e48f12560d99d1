"""The bus queue's order of service, bound and coalescing (pure logic, no port)."""

from __future__ import annotations

import asyncio
import itertools
import random

import pytest

from gateway.bus.line_share import LineShares
from gateway.bus.queue import Priority, RequestQueue, Transaction
from gateway.errors import GatewayPathUnavailable, QueueFull

READ = bytes.fromhex("03 21 00 00 03")


def txn(
    client: str,
    priority: Priority = Priority.READ,
    pdu: bytes = READ,
    address: int = 1,
    coalescable: bool = False,
) -> Transaction:
    waiter: asyncio.Future[bytes | None] = asyncio.get_running_loop().create_future()
    return Transaction(address, pdu, priority, client, 0.3, 2, coalescable, [waiter])


def order(queue: RequestQueue | _WeighedAlways) -> list[str]:
    taken = []
    while (t := queue.get_nowait()) is not None:
        taken.append(t.client)
    return taken


async def test_writes_before_reads_before_polls() -> None:
    queue = RequestQueue(10)
    queue.put(txn("poll", Priority.POLL))
    queue.put(txn("read", Priority.READ))
    queue.put(txn("write", Priority.WRITE))
    assert order(queue) == ["write", "read", "poll"]


async def test_round_robin_between_clients_of_one_priority() -> None:
    queue = RequestQueue(20)
    for _ in range(4):
        queue.put(txn("busy"))
    queue.put(txn("quiet"))
    # The quiet client waits behind one request of the busy one, not four.
    assert order(queue) == ["busy", "quiet", "busy", "busy", "busy"]


async def test_identical_reads_share_one_transaction() -> None:
    queue = RequestQueue(10)
    first = txn("a", coalescable=True)
    second = txn("b", coalescable=True)
    assert queue.put(first) is first
    assert queue.put(second) is first
    assert len(queue) == 1
    assert len(first.waiters) == 2
    taken = queue.get_nowait()
    assert taken is first
    # Once on the wire it no longer collects: a later read gets a fresh transaction.
    third = txn("c", coalescable=True)
    assert queue.put(third) is third


async def test_different_registers_are_not_coalesced() -> None:
    queue = RequestQueue(10)
    queue.put(txn("a", coalescable=True))
    other = txn("b", pdu=bytes.fromhex("03 30 00 00 0C"), coalescable=True)
    assert queue.put(other) is other
    assert len(queue) == 2


async def test_full_queue_refuses_with_gateway_path_unavailable() -> None:
    queue = RequestQueue(2)
    queue.put(txn("a"))
    queue.put(txn("a"))
    with pytest.raises(QueueFull) as caught:
        queue.put(txn("b"))
    assert isinstance(caught.value, GatewayPathUnavailable)
    assert caught.value.code == 0x0A


async def test_a_request_whose_callers_left_is_not_wanted() -> None:
    gone = txn("a")
    waiter = gone.waiters[0]
    assert isinstance(waiter, asyncio.Future)  # txn() waits with a future
    waiter.cancel()  # the client disconnected while it waited
    assert not gone.wanted()
    assert txn("b").wanted()
    probe = Transaction(
        1, bytes.fromhex("08 00 00 00 00"), Priority.READ, "probe", 0.3, 0, probe=True
    )
    assert probe.wanted()  # nobody waits for a probe, yet it must go out


async def test_polls_get_a_share_while_reads_keep_coming() -> None:
    """Without line time charged yet, the share is not reached: a poll goes once every client
    waiting to read had its read."""
    queue = RequestQueue(100)
    for i in range(12):
        queue.put(txn(f"scada{i % 3}"))
    for _ in range(3):
        queue.put(txn("poll", Priority.POLL))
    queue.put(txn("write", Priority.WRITE))
    served = order(queue)
    assert served[0] == "write"  # writes still go first
    assert [i for i, c in enumerate(served[1:], 1) if c == "poll"] == [4, 8, 12]


def serve_a_full_line(
    queue: RequestQueue, clients: list[str], transactions: int, poll_s: float = 0.01
) -> tuple[list[str], float]:
    """Clients reading without pause (each asks again once answered) and polls always
    waiting, each transaction charged its line time (reads 10 ms, polls `poll_s`): the order
    served, and the polls' share of the line's time."""
    for client in clients:
        queue.put(txn(client))
    now = poll_time = 0.0
    served: list[str] = []
    for _ in range(transactions):
        if len(queue) == len(clients):  # no poll waiting: the poller's next, always due
            queue.put(txn("poll", Priority.POLL))
        taken = queue.get_nowait(now)
        assert taken is not None
        seconds = poll_s if taken.client == "poll" else 0.01
        now += seconds
        queue.charge(taken, seconds, now)
        served.append(taken.client)
        if taken.client == "poll":
            poll_time += seconds
        else:
            queue.put(txn(taken.client))
    return served, poll_time / now


async def test_polls_take_at_most_their_share_of_a_full_line() -> None:
    """A full line's readers wait for every second the polls take: while reads wait, polls
    get `poll_share` of the line (5 % by default), longer polls fewer turns, and still go."""
    clients = [f"scada{n}" for n in range(8)]
    served, share = serve_a_full_line(RequestQueue(100), clients, 2000)
    assert 0.03 < share <= 0.055
    long_polls, long_share = serve_a_full_line(RequestQueue(100), clients, 2000, poll_s=0.03)
    assert 0.03 < long_share <= 0.055
    assert long_polls.count("poll") < served.count("poll") / 2
    # A larger share: then the other rule binds, a poll once every waiting client had its
    # read (one transaction in nine with eight readers).
    shares = LineShares(poll_share=0.5)
    _, more = serve_a_full_line(RequestQueue(100, shares), clients, 2000)
    assert 0.1 < more <= 1 / 9 + 0.001


async def test_a_poll_holds_a_waiting_client_for_one_poll_transaction_at_most() -> None:
    """Eight SCADA connections reading without pause (each asks again while the next
    transaction is on the wire) and polls always waiting: a poll goes once every client had
    its turn, so between two of a client's reads at most one poll; and polls still go."""
    queue = RequestQueue(100)
    clients = [f"scada{n}" for n in range(8)]
    for client in clients:
        queue.put(txn(client))
    for _ in range(20):
        queue.put(txn("poll", Priority.POLL))
    served: list[str] = []
    in_transit: str | None = None  # answered, its next read not yet queued
    for _ in range(60):
        taken = queue.get_nowait()
        assert taken is not None
        served.append(taken.client)
        if in_transit is not None:
            queue.put(txn(in_transit))
        in_transit = taken.client if taken.client != "poll" else None
    polls = served.count("poll")
    assert polls >= 5  # telemetry goes on under the SCADA's load
    for client in clients:
        turns = [i for i, c in enumerate(served) if c == client]
        for before, after in itertools.pairwise(turns):
            assert served[before + 1 : after].count("poll") <= 1, (client, served)


class _WeighedAlways:
    """The queue without its shortcut for a transaction waiting alone: every choice weighed by
    the rules, as before the shortcut existed. (A wrapper, not a subclass: RequestQueue may be
    compiled by mypyc, whose classes take no subclass in Python.)"""

    def __init__(self, limit: int) -> None:
        self.queue = RequestQueue(limit)

    def put(self, transaction: Transaction) -> Transaction:
        carrier = self.queue.put(transaction)
        self.queue._alone = None
        return carrier

    def get_nowait(self, now: float | None = None) -> Transaction | None:
        return self.queue.get_nowait(now)

    def charge(self, transaction: Transaction, held_s: float, now: float) -> None:
        self.queue.charge(transaction, held_s, now)


async def test_a_transaction_waiting_alone_is_served_as_the_rules_would_serve_it() -> None:
    """Random mixes of reads, polls, writes and broadcasts from a few clients, arriving one by
    one or in bursts between services: the queue with its shortcut serves them in the same
    order, with the same polls' turns, as the queue that weighs every choice."""
    rng = random.Random(7)
    kinds = [
        ("scada", Priority.READ, 1),
        ("hmi", Priority.READ, 2),
        ("poll", Priority.POLL, 1),
        ("mqtt", Priority.WRITE, 1),
        ("plc", Priority.WRITE, 0),  # a broadcast
    ]
    alone = 0
    for _ in range(50):
        shortcut, weighed = RequestQueue(1000), _WeighedAlways(1000)
        queues: tuple[RequestQueue | _WeighedAlways, ...] = (shortcut, weighed)
        served: tuple[list[str], list[str]] = ([], [])
        now = 0.0
        for _ in range(rng.randint(5, 60)):
            for _ in range(rng.choice([0, 0, 0, 1, 1, 1, 1, 2, 3])):
                client, priority, address = rng.choice(kinds)
                pdu = bytes((rng.choice([3, 6]), 0x21, 0, 0, rng.randint(1, 3)))
                for queue in queues:
                    queue.put(txn(client, priority, pdu, address))
            now += rng.uniform(0.001, 0.05)
            held_s = rng.uniform(0.002, 0.03)  # the same line time in both
            alone += shortcut._alone is not None
            for queue, names in zip(queues, served, strict=True):
                taken = queue.get_nowait(now)
                if taken is not None:
                    queue.charge(taken, held_s, now)
                    names.append(f"{taken.client}:{taken.pdu.hex()}")
        assert served[0] == served[1]
        assert order(shortcut) == order(weighed)
    assert alone > 200  # the shortcut was taken, often
