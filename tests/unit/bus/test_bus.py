"""The bus on its own, over a real pty with simulated drives: the manual's frames answered
byte-exact, the gap kept between back-to-back requests, a silent drive retried then isolated,
broadcasts unanswered, identical reads sharing one transaction, and a closing bus answering what
it still held."""

from __future__ import annotations

import asyncio
import time

import pytest

from gateway.bus import Bus
from gateway.bus.bus import RequestDone
from gateway.bus.line import Exchange
from gateway.bus.queue import Priority
from gateway.errors import BusClosed, DriveOffline, GatewayTargetFailed
from gateway.instruments.simulator import SimulatedLine
from gateway.modbus.timing import FAST_T35_S
from tests.support import eventually, read_pdu, running_bus, write_pdu

STATE_WORD_1 = 0x2100
FREQUENCY_SETPOINT = 0x2001
STOPPED = 3
STOPPED_REPLY = bytes.fromhex("03 02 00 03")
RUNNING_VALUES = 0x3000
SILENT = 9
"""An address nobody answers on."""

pytestmark = pytest.mark.line(addresses=[1, 2])


async def read(bus: Bus, address: int, register: int, count: int = 1) -> bytes | None:
    return await bus.request(address, read_pdu(register, count), priority=Priority.READ, client="t")


async def test_the_manuals_read_of_state_word_1_is_answered_byte_exact(line: SimulatedLine) -> None:
    # PROTOCOL.md: 01 03 21 00 00 01 8E 36 reads state word 1; 3 is "stopped".
    async with running_bus(line.path) as bus:
        assert await read(bus, 1, STATE_WORD_1) == bytes.fromhex("03 02 00 03")
        assert bus.stats.transactions == 1
        assert bus.drive_stats[1].transactions == 1


async def test_back_to_back_requests_keep_the_inter_frame_gap(line: SimulatedLine) -> None:
    async with running_bus(line.path) as bus:
        replies = await asyncio.gather(*(read(bus, 1 + n % 2, STATE_WORD_1) for n in range(20)))
        assert set(replies) == {bytes.fromhex("03 02 00 03")}
        assert bus.stats.min_gap_s is not None
        assert bus.stats.min_gap_s >= FAST_T35_S  # 115200 baud: 1.75 ms, never shorter
        # Requests that were already waiting when a reply ended: our own time between them.
        assert bus.gap_excess.count > 0
        assert bus.gap_excess.counts[0] == 0  # no gap shorter than t3.5


async def test_a_silent_drive_is_retried_then_isolated_without_the_line(
    line: SimulatedLine,
) -> None:
    heard: list[tuple[int, bool]] = []
    async with running_bus(line.path, timeout_ms=50, retries=1, offline_after=2) as bus:
        bus.add_listener(lambda _bus, address, online: heard.append((address, online)))
        for _ in range(2):
            with pytest.raises(GatewayTargetFailed):
                await read(bus, SILENT, STATE_WORD_1)
        # The first request is tried twice; a drive that just failed gets no retries, so the
        # second costs the line one timeout only.
        assert (bus.stats.timeouts, bus.stats.retries) == (3, 1)
        assert bus.health.is_offline(SILENT)
        assert heard == [(SILENT, False)]
        sent = line.stats["requests"]
        with pytest.raises(DriveOffline):
            await read(bus, SILENT, STATE_WORD_1)
        assert line.stats["requests"] == sent  # refused at once, no line time spent
        assert bus.stats.offline_rejected == 1
        assert await read(bus, 1, STATE_WORD_1) == bytes.fromhex("03 02 00 03")  # others unhurt


async def test_a_broadcast_is_not_answered_yet_every_drive_obeys(line: SimulatedLine) -> None:
    async with running_bus(line.path) as bus:
        reply = await bus.request(
            0, write_pdu(FREQUENCY_SETPOINT, 2500), priority=Priority.WRITE, client="t"
        )
        assert reply is None
        assert bus.stats.broadcasts == 1
        for address in (1, 2):
            assert await read(bus, address, FREQUENCY_SETPOINT) == bytes.fromhex("03 02 09 C4")


async def test_identical_reads_waiting_together_share_one_transaction(
    line: SimulatedLine,
) -> None:
    line.set_reply_delay(2, 100)  # drive 2 holds the line while the reads queue up
    async with running_bus(line.path) as bus:
        busy = asyncio.create_task(read(bus, 2, STATE_WORD_1))
        await eventually(lambda: bus.busy, what="the slow request on the wire")
        readers = [asyncio.create_task(read(bus, 1, 0x3000, 6)) for _ in range(5)]
        replies = await asyncio.gather(*readers)
        await busy
        assert len(set(replies)) == 1
        assert bus.stats.coalesced == 4
        assert bus.stats.transactions == 2


async def test_reads_submitted_in_one_call_are_shared_counted_and_observed_as_any_other(
    line: SimulatedLine,
) -> None:
    """`submit` with a waiter, the Modbus-TCP server's way to the bus: identical reads waiting
    together share a transaction, every request is counted and its observers told, and an
    offline drive's read is refused (0BH) before it is queued."""
    line.set_reply_delay(2, 100)  # drive 2 holds the line while the reads queue up
    async with running_bus(line.path, timeout_ms=300, retries=0, offline_after=1) as bus:
        done: list[RequestDone] = []
        bus.add_request_observer(lambda *fields: done.append(RequestDone(*fields)))
        loop = asyncio.get_running_loop()
        busy = asyncio.create_task(read(bus, 2, STATE_WORD_1))
        await eventually(lambda: bus.busy, what="the slow request on the wire")
        readers: list[asyncio.Future[bytes | None]] = [loop.create_future() for _ in range(3)]
        for n, reader in enumerate(readers):
            bus.submit(1, read_pdu(STATE_WORD_1), reader, Priority.READ, f"c{n}")
        assert await asyncio.gather(*readers) == [STOPPED_REPLY] * 3
        await busy
        assert bus.stats.coalesced == 2
        assert bus.stats.transactions == 2
        with pytest.raises(GatewayTargetFailed):
            await read(bus, SILENT, STATE_WORD_1)  # offline from now (offline_after 1)
        refused: asyncio.Future[bytes | None] = loop.create_future()
        with pytest.raises(DriveOffline):
            bus.submit(SILENT, read_pdu(STATE_WORD_1), refused, Priority.READ, "c0")
        assert bus.stats.offline_rejected == 1
        assert bus.stats.requests == 6
        assert sorted((d.address, d.client, d.code) for d in done) == [
            (1, "c0", None),
            (1, "c1", None),
            (1, "c2", None),
            (2, "t", None),
            (SILENT, "c0", 0x0B),
            (SILENT, "t", 0x0B),
        ]


async def test_a_read_submitted_in_one_call_is_observed_however_it_ends(
    line: SimulatedLine,
) -> None:
    """The observers hear of a `submit`ted read's outcome once, with its exception code, on
    every way it can end: answered, answered with the drive's exception, timed out, answered
    by the closing bus; and not at all when its client went before the answer."""
    line.set_reply_delay(2, 100)  # drive 2 holds the line while the reads queue up
    async with running_bus(line.path, timeout_ms=300, retries=0, offline_after=5) as bus:
        done: list[RequestDone] = []
        bus.add_request_observer(lambda *fields: done.append(RequestDone(*fields)))
        loop = asyncio.get_running_loop()

        def submit(address: int, pdu: bytes, client: str) -> asyncio.Future[bytes | None]:
            waiter: asyncio.Future[bytes | None] = loop.create_future()
            bus.submit(address, pdu, waiter, Priority.READ, client)
            return waiter

        assert await submit(1, read_pdu(STATE_WORD_1), "answered") == STOPPED_REPLY
        refused = await submit(1, read_pdu(0xFFFF), "refused")
        assert refused is not None
        assert refused[0] == 0x83
        with pytest.raises(GatewayTargetFailed):
            await submit(SILENT, read_pdu(STATE_WORD_1), "timed-out")
        busy = submit(2, read_pdu(STATE_WORD_1), "busy")
        await eventually(lambda: bus.busy, what="the slow request on the wire")
        gone = submit(1, read_pdu(RUNNING_VALUES), "gone")
        closed = submit(1, read_pdu(FREQUENCY_SETPOINT), "closed")
        gone.cancel()  # its client went while it waited
        bus.close()
        with pytest.raises(BusClosed):
            await closed
        assert await busy == STOPPED_REPLY
        assert [(d.address, d.client, d.code) for d in done] == [
            (1, "answered", None),
            (1, "refused", refused[1]),
            (SILENT, "timed-out", 0x0B),
            (1, "closed", 0x0B),
            (2, "busy", None),
        ]
        assert all(d.duration_s > 0 for d in done)


async def test_closing_answers_the_queued_requests_with_bus_closed(line: SimulatedLine) -> None:
    line.set_reply_delay(1, 100)
    async with running_bus(line.path) as bus:
        on_the_wire = asyncio.create_task(read(bus, 1, STATE_WORD_1))
        await eventually(lambda: bus.busy, what="the first request on the wire")
        queued = asyncio.create_task(read(bus, 2, STATE_WORD_1))
        await eventually(lambda: bus.queue_depth == 1, what="the second request queued")
        bus.close()
        with pytest.raises(BusClosed):
            await queued
        # The transaction on the wire is not cut off: the drive's answer still arrives.
        assert await on_the_wire == bytes.fromhex("03 02 00 03")
        with pytest.raises(BusClosed):
            await read(bus, 1, STATE_WORD_1)


async def test_a_silent_drive_times_out_at_the_requests_own_timeout(line: SimulatedLine) -> None:
    """The bus's default is a second; a route's (or a probe's) shorter timeout is what counts.
    A drive that is silent keeps the line for that long and no longer."""
    async with running_bus(line.path, timeout_ms=1000, retries=0, offline_after=5) as bus:
        loop = asyncio.get_running_loop()
        started = loop.time()
        with pytest.raises(GatewayTargetFailed):
            await bus.request(
                SILENT, read_pdu(STATE_WORD_1), priority=Priority.READ, client="t", timeout_s=0.05
            )
        assert loop.time() - started < 0.5  # 50 ms and the gap, far from the bus's 1 s
        # And the line is free at once for the next request, answered as usual.
        assert await read(bus, 1, STATE_WORD_1) == bytes.fromhex("03 02 00 03")


async def test_transactions_ended_in_the_reader_callback_are_counted_as_any_other(
    line: SimulatedLine,
) -> None:
    """Back-to-back reads end in the port's reader callback, a silent drive's in the bus's own
    reading: both are counted, timed and shown to the traffic monitor alike, and only requests
    that waited for the line count in the gateway's own share (the excess gap)."""
    seen: list[tuple[int, int, bool]] = []
    async with running_bus(line.path, timeout_ms=50, retries=0, offline_after=5) as bus:
        after_the_gap = 10 * bus.settings.line.gap_s  # a request then finds the line idle
        bus.tap = lambda _bus, transaction, attempt, _started, outcome: seen.append(
            (transaction.address, attempt, isinstance(outcome, Exchange))
        )
        assert await read(bus, 1, STATE_WORD_1) == STOPPED_REPLY  # alone: waited for nobody
        await asyncio.sleep(after_the_gap)
        # Running values 3000H on, 1-5 words: no two alike, so none share a transaction.
        counts = [1 + n // 2 for n in range(10)]
        replies = await asyncio.gather(
            *(read(bus, 1 + n % 2, RUNNING_VALUES, count) for n, count in enumerate(counts))
        )
        assert [reply[:2] if reply else None for reply in replies] == [
            bytes([3, 2 * count]) for count in counts
        ]
        await asyncio.sleep(after_the_gap)
        with pytest.raises(GatewayTargetFailed):
            await read(bus, SILENT, STATE_WORD_1)
        assert bus.stats.transactions == 12
        assert (bus.drive_stats[1].transactions, bus.drive_stats[2].transactions) == (6, 5)
        assert bus.stats.timeouts == bus.drive_stats[SILENT].timeouts == 1
        assert all(bus.drive_stats[address].line_s > 0 for address in (1, 2, SILENT))
        assert bus.stats.busy_s > 0
        # The 10 gathered reads: the first came after the gap and waited for nobody, each of
        # the 9 after it for the reply before it; the lone read and the silent drive's request
        # waited for nobody.
        assert bus.gap_excess.count == 9
        assert bus.gap_excess.counts[0] == 0  # never a gap shorter than t3.5
    assert seen == [(1, 0, True)] + [(1 + n % 2, 0, True) for n in range(10)] + [(SILENT, 0, False)]


@pytest.mark.line(baudrate=1200)
async def test_a_request_queued_during_the_gap_counts_in_the_gateways_share(
    line: SimulatedLine,
) -> None:
    """Clients answered together by a shared transaction ask again together, after the reply
    ended but before the gap that follows it has: they waited for the line, so the silence
    beyond t3.5 before them is the gateway's own and counts. A request after the gap found the
    line idle (a client's own pause) and does not."""
    async with running_bus(line.path, baudrate=1200) as bus:
        gap_s = bus.settings.line.gap_s  # 32 ms at 1200 baud: a coroutine asks again well within
        assert await read(bus, 1, STATE_WORD_1) == STOPPED_REPLY
        assert bus.gap_excess.count == 0  # the first request: no reply before it
        assert await read(bus, 1, STATE_WORD_1) == STOPPED_REPLY  # asked again at once
        assert bus.gap_excess.count == 1
        await asyncio.sleep(3 * gap_s)
        assert await read(bus, 2, STATE_WORD_1) == STOPPED_REPLY  # after the gap: line idle
        assert bus.gap_excess.count == 1
        assert bus.gap_excess.counts[0] == 0  # never a gap shorter than t3.5


@pytest.mark.line(baudrate=1200)
async def test_a_request_the_late_gateway_finds_waiting_counts_from_its_queueing(
    line: SimulatedLine,
) -> None:
    """The gateway stalls through the gap after a reply (the loop held up, as by a slow
    wake-up) and a request is queued after the gap has ended but before the gateway gets to
    it: it waited for the gateway, so it counts (leaving it out would hide the late wake-ups),
    and only from its queueing (before it, the line waited for a request)."""
    async with running_bus(line.path, baudrate=1200) as bus:
        gap_s = bus.settings.line.gap_s  # 32 ms at 1200 baud
        assert await read(bus, 1, STATE_WORD_1) == STOPPED_REPLY
        assert bus.gap_excess.count == 0  # the first request: no reply before it
        loop = asyncio.get_running_loop()
        late: asyncio.Future[bytes | None] = loop.create_future()

        def stall_then_ask() -> None:
            time.sleep(2 * gap_s)  # the whole gap and as long again: the gateway asleep
            bus.submit(1, read_pdu(STATE_WORD_1, 1), late, priority=Priority.READ, client="t")

        loop.call_soon(stall_then_ask)
        assert await late == STOPPED_REPLY
        assert bus.gap_excess.count == 1
        assert bus.gap_excess.counts[0] == 0  # never a gap shorter than t3.5
        # Counted from its queueing, not from the gap's end a gap's length before.
        assert bus.gap_excess.sum_s < gap_s / 2


@pytest.mark.line(baudrate=1200)
async def test_after_a_timeout_or_a_broadcast_the_next_gap_is_not_the_gateways_share(
    line: SimulatedLine,
) -> None:
    """A request that waited behind a silent drive's timeout, or behind a broadcast's
    turnaround, follows no reply: the silence before it is the drive's or the protocol's, not
    the gateway's, and stays out of the histogram even though the request was waiting."""
    # 400 ms: long enough for a simulated drive on a loaded machine (at 100 ms, 1 run in 6 of
    # this file timed out the first read with 4 benches beside it), short for the silent one.
    async with running_bus(line.path, baudrate=1200, timeout_ms=400, retries=0) as bus:
        assert await read(bus, 1, STATE_WORD_1) == STOPPED_REPLY
        after_silence = asyncio.gather(
            read(bus, SILENT, STATE_WORD_1), read(bus, 1, STATE_WORD_1), return_exceptions=True
        )
        timed_out, answered = await after_silence
        assert isinstance(timed_out, GatewayTargetFailed)
        assert answered == STOPPED_REPLY
        counted = bus.gap_excess.count  # the silent drive's request followed the first reply
        assert counted == 1
        broadcast = bus.request(
            0, write_pdu(FREQUENCY_SETPOINT, 1000), priority=Priority.WRITE, client="t"
        )
        assert list(await asyncio.gather(broadcast, read(bus, 2, STATE_WORD_1))) == [
            None,
            STOPPED_REPLY,
        ]
        # The broadcast waited for the gap after a reply (counted); the read behind it waited
        # out the broadcast's turnaround (not counted).
        assert bus.gap_excess.count == counted + 1
        assert bus.gap_excess.counts[0] == 0


async def test_a_traffic_monitor_that_fails_costs_no_request_its_answer(
    line: SimulatedLine, caplog: pytest.LogCaptureFixture
) -> None:
    """The console's tap is told of every attempt; a bug in it is logged, and every request
    still gets its drive's answer, answered in the reader callback or by a timeout alike."""

    def failing_tap(*_attempt: object) -> None:
        raise RuntimeError("a bug in the traffic monitor")

    async with running_bus(line.path, timeout_ms=50, retries=0, offline_after=5) as bus:
        bus.tap = failing_tap
        replies = await asyncio.gather(*(read(bus, 1 + n % 2, STATE_WORD_1) for n in range(6)))
        assert replies == [STOPPED_REPLY] * 6
        with pytest.raises(GatewayTargetFailed, match=r"timeout|no reply"):
            await read(bus, SILENT, STATE_WORD_1)  # the silent drive's own failure, not 0BH's
        attempts = bus.stats.transactions  # identical reads shared theirs
    failures = [r for r in caplog.records if "traffic monitor's tap failed" in r.getMessage()]
    assert len(failures) == attempts >= 3


async def test_a_closed_bus_refuses_with_the_reason_it_was_closed_for(line: SimulatedLine) -> None:
    """A bus closed for a reason (the standby's, another master heard) says so to whoever asks
    next, not "shutting down"."""
    async with running_bus(line.path) as bus:
        bus.close("is not served by this gateway: it is the standby")
        with pytest.raises(BusClosed, match="it is the standby"):
            await read(bus, 1, STATE_WORD_1)
