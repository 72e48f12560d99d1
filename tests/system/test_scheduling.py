"""How the bus spends the line: priorities, fairness, coalescing, splitting, RAM writes, the gap.

Checked by behaviour (order, counts, values on the simulated drives), never by timing thresholds;
the figures are `invt-gateway bench`'s job.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import struct
import time
from collections.abc import AsyncIterator, Iterator

import pytest

from gateway.app import Application
from gateway.bus import Priority, RequestDone
from gateway.bus.queue import Transaction
from gateway.errors import GatewayTargetFailed
from gateway.instruments.simulator import SimulatedLine
from gateway.modbus.timing import CharacterFormat
from gateway.routing import POLL_CLIENT
from tests.support import (
    TcpClient,
    eventually,
    gateway_config,
    read_pdu,
    running_gateway,
    write_pdu,
)

DRIVES = [{"name": "pump1", "address": 1}, {"name": "fan2", "address": 2}]


@pytest.fixture
def slow_line() -> Iterator[SimulatedLine]:
    """9600 baud with wire time: a transaction takes ~30 ms, long enough for a queue to form."""
    with SimulatedLine(addresses=[1, 2], baudrate=9600, wire_time=True) as line:
        yield line


async def occupy_line(app: Application, line: SimulatedLine) -> asyncio.Task[bytes | None]:
    """Put one slow transaction on the wire and wait until it is there, so the next ones queue
    behind it however busy the machine running the test is."""
    line.set_reply_delay(2, 150)
    seen = line.stats["requests"]
    busy = asyncio.create_task(app.router.execute(2, read_pdu(0x3000, 16), client="occupier"))
    await eventually(lambda: line.stats["requests"] > seen, what="the drive has the request")
    return busy


async def test_writes_go_before_reads_and_reads_before_polls(slow_line: SimulatedLine) -> None:
    async with running_gateway(
        gateway_config(slow_line.path, DRIVES, baudrate=9600, timeout_ms=1000)
    ) as app:
        finished: list[str] = []

        async def send(label: str, pdu: bytes, priority: Priority | None) -> None:
            await app.router.execute(1, pdu, client=label, priority=priority)
            finished.append(label)

        busy = await occupy_line(app, slow_line)
        jobs = [send("poll", read_pdu(0x3000 + i), Priority.POLL) for i in range(2)] + [
            send("read", read_pdu(0x2100 + i), None) for i in range(2)
        ]
        jobs.append(send("write", write_pdu(0x0005, 123), None))
        await asyncio.gather(busy, *jobs)
        assert finished == ["write", "read", "read", "poll", "poll"]


async def test_the_next_request_is_chosen_when_the_gap_ends_not_when_it_begins(
    slow_line: SimulatedLine,
) -> None:
    """A read waits while a transaction is on the wire; a write comes during the gap after it:
    the write goes first, because the bus chooses in the wake-up that ends the gap (a long gap
    makes the order sure however slow the machine)."""
    config = gateway_config(slow_line.path, DRIVES, baudrate=9600, timeout_ms=1000, gap_ms=400)
    async with running_gateway(config) as app:
        finished: list[str] = []

        async def send(label: str, pdu: bytes) -> None:
            await app.router.execute(1, pdu, client=label)
            finished.append(label)

        busy = await occupy_line(app, slow_line)
        read = asyncio.create_task(send("read", read_pdu(0x2101)))  # queued before the gap
        await busy  # the gap starts now
        await asyncio.sleep(0.02)  # the thing under test: a write that arrives inside the gap
        write = asyncio.create_task(send("write", write_pdu(0x0005, 321)))
        await asyncio.gather(read, write)
        assert finished == ["write", "read"]
        min_gap = app.buses["line1"].stats.min_gap_s
        assert min_gap is not None
        assert min_gap >= 0.4


async def test_bytes_arriving_during_the_gap_start_it_again(slow_line: SimulatedLine) -> None:
    """Noise on the line in the middle of a gap: the next request waits a whole gap after it,
    and the noise is thrown away, not taken for the reply."""
    config = gateway_config(slow_line.path, DRIVES, baudrate=9600, timeout_ms=1000, gap_ms=300)
    async with running_gateway(config) as app:
        line = app.buses["line1"].line
        await app.router.execute(1, read_pdu(0x2100), client="first")  # the gap starts now
        queued = asyncio.create_task(app.router.execute(1, read_pdu(0x2100), client="next"))
        await asyncio.sleep(0.15)  # the thing under test: noise in the middle of the 300 ms gap
        slow_line.write_raw(b"\x00\xff")
        noise_sent = time.monotonic()
        assert await queued == bytes.fromhex("03 02 00 03")
        # The reply comes back after the request went out, which is a whole gap after the noise.
        assert time.monotonic() - noise_sent >= 0.3
        assert line.discarded_bytes == 2


async def test_a_busy_client_does_not_starve_another(slow_line: SimulatedLine) -> None:
    async with running_gateway(
        gateway_config(slow_line.path, DRIVES, baudrate=9600, timeout_ms=1000)
    ) as app:
        finished: list[str] = []

        async def send(label: str, register: int) -> None:
            await app.router.execute(1, read_pdu(register), client=label)
            finished.append(label)

        busy = await occupy_line(app, slow_line)
        jobs = [send("busy", 0x3000 + i) for i in range(5)]
        jobs.append(send("quiet", 0x2100))  # queued last
        await asyncio.gather(busy, *jobs)
        assert finished.index("quiet") <= 1  # served after one of the busy client's, not five


async def test_identical_waiting_reads_share_one_transaction(slow_line: SimulatedLine) -> None:
    async with running_gateway(
        gateway_config(slow_line.path, DRIVES, baudrate=9600, timeout_ms=1000)
    ) as app:
        clients = [await TcpClient.connect(app.tcp.port) for _ in range(8)]
        busy = await occupy_line(app, slow_line)
        before = slow_line.stats["requests"]
        replies = await asyncio.gather(*(c.read(1, 0x2100, 4) for c in clients))
        await busy
        assert all(reply == replies[0] for reply in replies)
        assert replies[0][0] == 3  # stopped: a true value
        # One transaction for the eight reads (the occupier was already counted).
        assert slow_line.stats["requests"] - before == 1
        assert app.buses["line1"].stats.coalesced == 7
        for client in clients:
            await client.close()


async def test_reads_over_16_words_are_split_and_reassembled() -> None:
    with SimulatedLine(addresses=[1], baudrate=115200) as line:
        config = gateway_config(line.path, [{"name": "pump1", "address": 1, "model": "gd350"}])
        async with running_gateway(config) as app:
            client = await TcpClient.connect(app.tcp.port)
            before = line.stats["requests"]
            whole = await client.read(1, 0x3000, 23)
            assert line.stats["requests"] - before == 2  # 16 + 7 words: INVT's limit
            assert whole[:16] == await client.read(1, 0x3000, 16)
            assert whole[16:] == await client.read(1, 0x3010, 7)
            assert whole[0x16] == line.drives[1].identification  # 3016H
            # A part the drive refuses fails the whole, with the drive's own exception.
            assert await client.request(1, read_pdu(0x3010, 20)) == bytes.fromhex("83 02")
            await client.close()


async def test_without_splitting_the_drive_refuses_more_than_16_words() -> None:
    with SimulatedLine(addresses=[1], baudrate=115200) as line:
        drives = [{"name": "pump1", "address": 1, "split": False}]
        async with running_gateway(gateway_config(line.path, drives)) as app:
            client = await TcpClient.connect(app.tcp.port)
            reply = await client.request(1, read_pdu(0x3000, 23))
            assert reply[0] == 0x83  # the drive's own refusal, passed through
            await client.close()


async def test_ram_writes_spare_the_eeprom() -> None:
    with SimulatedLine(addresses=[1, 2], baudrate=115200) as line:
        drives = [
            {"name": "pump1", "address": 1, "ram_writes": True},
            {"name": "fan2", "address": 2},
        ]
        async with running_gateway(gateway_config(line.path, drives)) as app:
            client = await TcpClient.connect(app.tcp.port)
            # P00.11 = 5.0 s: the client sees its own address echoed, the drive got 800BH.
            assert await client.request(1, write_pdu(0x000B, 50)) == write_pdu(0x000B, 50)
            assert await client.read(1, 0x000B) == [50]
            assert (line.drives[1].ram_writes, line.drives[1].eeprom_writes) == (1, 0)
            # The control word is RAM already and is never redirected.
            assert await client.request(1, write_pdu(0x2001, 1000)) == write_pdu(0x2001, 1000)
            # A drive without ram_writes writes EEPROM as asked.
            assert await client.request(2, write_pdu(0x000B, 60)) == write_pdu(0x000B, 60)
            assert (line.drives[2].ram_writes, line.drives[2].eeprom_writes) == (0, 1)
            await client.close()


@pytest.mark.parametrize("baudrate", [9600, 115200])
async def test_the_inter_frame_gap_is_kept(baudrate: int) -> None:
    with SimulatedLine(addresses=[1, 2], baudrate=baudrate, wire_time=True) as line:
        config = gateway_config(line.path, DRIVES, baudrate=baudrate)
        async with running_gateway(config) as app:
            client = await TcpClient.connect(app.tcp.port)
            frames = b"".join(
                struct.pack(">HHHB", tid, 0, 6, 1 + tid % 2) + read_pdu(0x2100) for tid in range(40)
            )
            client.writer.write(frames)  # a burst: the queue never runs dry
            for _ in range(40):
                assert (await client.receive()).pdu == bytes.fromhex("03 02 00 03")
            t35 = CharacterFormat(baudrate, "E").t35_s
            # Measured on both sides of the line: the gateway's gap and the drive's view of it.
            assert line.stats["gap_violations"] == 0
            assert line.stats["min_gap_s"] >= t35
            min_gap = app.buses["line1"].stats.min_gap_s
            assert min_gap is not None
            assert min_gap >= t35
            await client.close()


async def test_reads_inside_a_polled_range_come_from_the_cache_never_stale() -> None:
    with SimulatedLine(addresses=[1], baudrate=115200) as line:
        drives = [
            {
                "name": "pump1",
                "address": 1,
                "cache_max_age_ms": 300,
                "poll": [{"name": "state", "start": 0x2100, "count": 3, "interval_ms": 100}],
            }
        ]
        config = gateway_config(line.path, drives, timeout_ms=50, retries=0, offline_after=1)
        async with running_gateway(config) as app:
            client = await TcpClient.connect(app.tcp.port)
            await eventually(lambda: app.poller.polls >= 3, what="a few polls")
            before = line.stats["requests"]
            for _ in range(20):
                state_word_1, _, fault = await client.read(1, 0x2100, 3)
                assert (state_word_1, fault) == (3, 0)
            # Twenty answers; on the line meanwhile only the polls' own transactions.
            assert line.stats["requests"] - before <= 3
            assert app.cache.hits >= 20
            # A read outside the polled range still goes to the drive.
            assert await client.read(1, 0x2103) == [line.drives[1].identification]
            # The drive trips by itself (no write through the gateway): the polls keep going
            # past the cache, so within the cache's age SCADA sees the fault.
            line.inject_fault(1, 35)

            async def shows_the_fault() -> bool:
                state_word_1, _, fault = await client.read(1, 0x2100, 3)
                return (state_word_1, fault) == (4, 35)

            # Cache 300 ms + a poll 100 ms, with room for a loaded machine.
            await eventually(shows_the_fault, within_s=1.0, every_s=0.02)
            # A write through the gateway: the next read can't return what it overwrote.
            await client.request(1, write_pdu(0x2000, 7))  # fault reset
            assert (await client.read(1, 0x2100, 3))[0] == 3
            # The drive goes silent: once the cache is older than 300 ms, no value comes from it.
            # A poll refills the cache after the write: the drive goes silent with a value cached.
            polls = app.poller.polls
            await eventually(lambda: app.poller.polls > polls, what="a poll after the write")
            line.set_dead(1, True)

            async def refused() -> bool:
                return await client.request(1, read_pdu(0x2100, 3)) == bytes.fromhex("83 0B")

            await eventually(refused, within_s=1.0, every_s=0.05)
            await client.close()


async def test_a_drive_comes_back_and_polls_run_while_scada_reads_without_pause() -> None:
    with SimulatedLine(addresses=[1, 2], baudrate=115200) as line:
        drives = [
            {"name": "pump1", "address": 1},
            {
                "name": "fan2",
                "address": 2,
                "poll": [{"name": "state", "start": 0x2100, "count": 3, "interval_ms": 50}],
            },
        ]
        line.set_dead(2, True)
        # 100 ms: short enough to find fan2 dead quickly, long enough that a loaded machine
        # running six busy clients never makes a healthy pump1 look dead.
        config = gateway_config(line.path, drives, timeout_ms=100, retries=0, offline_after=1)
        async with running_gateway(config) as app:
            bus = app.buses["line1"]
            # Distinct registers per client (nothing to coalesce), two requests in flight: the
            # queue never runs dry.
            async with scada_keeping_the_line_full(app, clients=6, unit=1) as load:
                # The poller finds fan2 dead and the bus isolates it.
                await eventually(lambda: bus.health.is_offline(2), within_s=4.0)
                line.set_dead(2, False)
                # Under the same load, a probe must find it and polls must read it again.
                polls_before = app.poller.polls
                await eventually(
                    lambda: not bus.health.is_offline(2) and app.poller.polls > polls_before + 3,
                    within_s=8.0,
                    what="fan2 probed back and polled again",
                )
                assert not any(task.done() for task in load)  # SCADA was served all along


@contextlib.asynccontextmanager
async def scada_keeping_the_line_full(
    app: Application, clients: int = 4, unit: int = 2
) -> AsyncIterator[list[asyncio.Task[None]]]:
    """SCADA connections reading `unit` without pause, two requests in flight each, so that a
    read always waits for the line; from the moment each has had a read answered until the
    block ends (then they stop and close). The block gets the clients' tasks: one done early
    is a client that stopped being served."""
    answered: set[int] = set()  # the clients that had a read answered
    stop = asyncio.Event()

    async def scada(client: TcpClient, register: int) -> None:
        while not stop.is_set():
            client.send(unit, read_pdu(register))
            client.send(unit, read_pdu(register))
            for _ in range(2):
                assert (await client.receive()).pdu[0] == 3
            answered.add(register)

    connected = [await TcpClient.connect(app.tcp.port) for _ in range(clients)]
    load = [asyncio.create_task(scada(c, 0x3000 + i)) for i, c in enumerate(connected)]
    try:
        await eventually(lambda: len(answered) == clients, what="the clients reading")
        yield load
    finally:
        stop.set()
        await asyncio.gather(*load)
        for client in connected:
            await client.close()


async def test_polls_yield_to_clients_reading_without_pause_and_fill_an_idle_line() -> None:
    """SCADA connections keeping the line full: a poll never holds one of them for more than
    one poll transaction, and polls take a small share of the line (`poll_share`, 5 % of its
    time by default; before it, one transaction in five here); once the clients stop, the
    poller gets every poll its plan asks for."""
    with SimulatedLine(addresses=[1, 2], baudrate=115200) as line:
        state = {"name": "state", "start": 0x2100, "count": 3, "interval_ms": 20}
        drives = [{"name": "pump1", "address": 1, "poll": [state]}, {"name": "fan2", "address": 2}]
        async with running_gateway(gateway_config(line.path, drives, timeout_ms=1000)) as app:
            served: list[str] = []  # who each transaction on the line was for, in order
            async with scada_keeping_the_line_full(app):
                bus = app.buses["line1"]
                bus.add_request_observer(lambda *done: served.append(RequestDone(*done).client))
                await eventually(
                    lambda: served.count(POLL_CLIENT) >= 6,
                    within_s=30.0,
                    what="polls under the load",
                )
                under_load = list(served)
            polls = under_load.count(POLL_CLIENT)
            assert polls / len(under_load) <= 0.1, under_load
            for reader in set(under_load) - {POLL_CLIENT}:
                turns = [n for n, who in enumerate(under_load) if who == reader]
                for before, after in itertools.pairwise(turns):
                    assert under_load[before + 1 : after].count(POLL_CLIENT) <= 1, under_load
            # The line idle: the polls take it all, one every 20 ms (ten asked for in 0.2 s,
            # given a few seconds on a loaded machine).
            polled = app.poller.polls
            await eventually(lambda: app.poller.polls >= polled + 10, what="polls on an idle line")


async def test_reads_of_a_client_that_left_cost_no_bus_time(slow_line: SimulatedLine) -> None:
    config = gateway_config(slow_line.path, DRIVES, baudrate=9600, timeout_ms=1000)
    async with running_gateway(config) as app:
        busy = await occupy_line(app, slow_line)
        before = slow_line.stats["requests"]
        leaving = await TcpClient.connect(app.tcp.port)
        for register in range(0x3000, 0x300C):  # twelve distinct reads, queued
            leaving.send(1, read_pdu(register))
        leaving.send(1, write_pdu(0x0005, 4321))
        bus = app.buses["line1"]
        await eventually(lambda: bus.queue_depth >= 13, what="its thirteen requests queued")
        await leaving.close()  # gone before any answer
        await busy
        await eventually(lambda: not bus.queue_depth and not bus.busy, what="the queue served")
        # The write it sent was carried out; its twelve reads were not (one may have been on
        # the wire already).
        assert slow_line.stats["requests"] - before <= 2
        stayer = await TcpClient.connect(app.tcp.port)
        assert await stayer.read(1, 0x0005) == [4321]
        await stayer.close()


async def test_a_drive_that_only_garbles_its_probes_backs_off_like_a_silent_one() -> None:
    """An offline drive whose every reply is corrupted (a wrong baud rate, a bad termination):
    its probes fail, so they come further and further apart, never at the first interval."""
    with SimulatedLine(addresses=[1], baudrate=115200) as line:
        config = gateway_config(line.path, [{"name": "pump1", "address": 1}], timeout_ms=50)
        async with running_gateway(config) as app:
            bus = app.buses["line1"]
            bus.health.probe_initial_s = 0.1
            line.set_dead(1, True)
            for _ in range(3):  # offline after three failed requests
                with pytest.raises(GatewayTargetFailed):
                    await app.router.execute(1, read_pdu(0x2100), client="scada")
            assert bus.health.is_offline(1)
            line.set_line_faults(1.0, ["crc"])
            line.set_dead(1, False)
            before = line.stats["requests"]
            await asyncio.sleep(1.6)  # the thing under test: probes counted over a fixed window
            probes = line.stats["requests"] - before
            # Doubling from 0.1 s: at most 0.1 + 0.2 + 0.4 + 0.8 s apart, 4 or 5 probes;
            # at the first interval it would be about 16.
            assert 1 <= probes <= 8
            assert bus.health.is_offline(1)


async def test_a_long_poll_goes_in_pieces_while_clients_wait_and_whole_on_an_idle_line() -> None:
    """A poll holds every waiting reader up for its transaction: while SCADA reads wait, a
    12-word poll goes as two 6-word reads (each the time of a short read, not of a long one);
    once the clients stop, as one read again. Seen on the wire through the bus's tap, as the
    console's traffic monitor shows it."""
    with SimulatedLine(addresses=[1, 2], baudrate=115200) as line:
        running = {"name": "running", "start": 0x3000, "count": 12, "interval_ms": 20}
        drives = [
            {"name": "pump1", "address": 1, "poll": [running]},
            {"name": "fan2", "address": 2},
        ]
        async with running_gateway(gateway_config(line.path, drives, timeout_ms=1000)) as app:
            polled: list[tuple[int, int]] = []  # (start, count) of each poll on the wire

            def tap(bus: str, transaction: Transaction, attempt: int, *_: object) -> None:
                if transaction.client == POLL_CLIENT and attempt == 0:
                    polled.append(struct.unpack(">HH", transaction.pdu[1:5]))

            async with scada_keeping_the_line_full(app):
                app.buses["line1"].tap = tap
                failures = app.poller.poll_failures
                await eventually(
                    lambda: len(polled) >= 6, within_s=30.0, what="polls under the load"
                )
                under_load = list(polled)
            assert set(under_load) <= {(0x3000, 6), (0x3006, 6)}, under_load
            assert (0x3006, 6) in under_load  # the second piece follows the first
            assert app.poller.poll_failures == failures
            # The line idle: the whole block in one read.
            polled.clear()
            await eventually(lambda: (0x3000, 12) in polled, what="a whole poll on an idle line")
