"""Clients that hold slots without doing anything, and clients that flood the line with writes:
neither may keep a well-behaved client out or starve its reads.

Real sockets against the gateway on a simulated line; what is asserted is what the other client
sees (it connects, it is served), and what the misbehaving ones get (closed, 0AH).
"""

from __future__ import annotations

import asyncio
import contextlib
import struct
import time
from collections.abc import AsyncIterator

import pytest

from gateway.instruments.simulator import SimulatedLine
from tests.support import (
    RecordProperty,
    TcpClient,
    eventually,
    protected_config,
    running_gateway,
    write_pdu,
)

STATE_WORD_1 = 0x2100
STOPPED = 3


# The same gateway and line as the other protection tests.
config = protected_config


async def open_from(host: str, port: int) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
    """A connection from another loopback address (127.0.0.N): another client, as far as the
    gateway can tell, so per-address limits see many clients."""
    return await asyncio.open_connection("127.0.0.1", port, local_addr=(host, 0))


@contextlib.asynccontextmanager
async def slow_senders(port: int, count: int, stop: asyncio.Event) -> AsyncIterator[list[int]]:
    """`count` clients from different addresses, each sending one byte of a frame per second and
    reconnecting as soon as they are closed. Yields the list of their reconnections so far."""
    reconnections = [0]

    async def one(index: int) -> None:
        host = f"127.0.0.{10 + index}"
        while not stop.is_set():
            try:
                reader, writer = await open_from(host, port)
            except OSError:
                await asyncio.sleep(0.05)  # a slow client's own pace before it tries again
                continue
            frame = struct.pack(">HHHB", 1, 0, 6, 1) + struct.pack(">BHH", 3, STATE_WORD_1, 1)
            try:
                for byte in frame[:-1]:  # never the last byte
                    writer.write(bytes((byte,)))
                    await writer.drain()
                    closed = asyncio.ensure_future(reader.read())
                    done, _ = await asyncio.wait({closed}, timeout=1.0)
                    if done or stop.is_set():
                        closed.cancel()
                        break
                    closed.cancel()
                else:
                    await reader.read()
            except (ConnectionError, OSError):
                pass
            finally:
                writer.close()
            reconnections[0] += 1

    tasks = [asyncio.create_task(one(i)) for i in range(count)]
    try:
        yield reconnections
    finally:
        stop.set()
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)


async def test_a_byte_now_and_then_does_not_keep_a_half_frame_open(line: SimulatedLine) -> None:
    async with running_gateway(config(line.path)) as app:
        reader, writer = await asyncio.open_connection("127.0.0.1", app.tcp.port)
        frame = struct.pack(">HHHB", 1, 0, 6, 1) + struct.pack(">BHH", 3, STATE_WORD_1, 1)
        started = time.monotonic()
        closed_after = None
        for byte in frame[:-1]:  # one byte a second: the half-frame limit restarted on each
            writer.write(bytes((byte,)))
            try:
                if await asyncio.wait_for(reader.read(), 1.0) == b"":
                    closed_after = time.monotonic() - started
                    break
            except TimeoutError:
                continue
        writer.close()
        # Closed 5 s after the frame's first byte, not 5 s after the last one.
        assert closed_after is not None, "a trickled frame kept its connection open"
        assert 4.5 < closed_after < 7.5
        assert app.tcp.stats.slow_closed == 1


async def test_a_connection_that_sends_nothing_is_closed_after_first_request_timeout(
    line: SimulatedLine,
) -> None:
    async with running_gateway(config(line.path, first_request_timeout_s=1)) as app:
        reader, writer = await asyncio.open_connection("127.0.0.1", app.tcp.port)
        started = time.monotonic()
        assert await asyncio.wait_for(reader.read(), 5) == b""
        assert 0.8 < time.monotonic() - started < 3
        writer.close()
        # A client that was served is not held to it.
        client = await TcpClient.connect(app.tcp.port)
        assert await client.read(1, STATE_WORD_1) == [STOPPED]
        await asyncio.sleep(1.5)  # the thing under test: idle past the first-request timeout
        assert await client.read(1, STATE_WORD_1) == [STOPPED]
        await client.close()
        assert app.tcp.stats.slow_closed == 1


async def test_one_address_can_not_take_every_slot(line: SimulatedLine) -> None:
    async with running_gateway(config(line.path, max_connections=6)) as app:
        # Half of max_connections by default: 3 from one address; a 4th is refused.
        mine = [await TcpClient.connect(app.tcp.port) for _ in range(3)]
        for client in mine:
            assert await client.read(1, STATE_WORD_1) == [STOPPED]
        reader, writer = await asyncio.open_connection("127.0.0.1", app.tcp.port)
        assert await asyncio.wait_for(reader.read(), 2) == b""
        writer.close()
        # Another address still gets in.
        other_reader, other_writer = await open_from("127.0.0.2", app.tcp.port)
        other = TcpClient(other_reader, other_writer)
        assert await other.read(2, STATE_WORD_1) == [STOPPED]
        for client in [*mine, other]:
            await client.close()


async def test_with_the_defaults_a_scada_host_connects_once_per_drive(
    line: SimulatedLine, record_property: RecordProperty
) -> None:
    # Several SCADA packages open one connection per device, and HMIs behind one NAT router
    # share an address: a full 32-drive line from one host must fit, with room for others.
    async with running_gateway(config(line.path)) as app:
        settings = app.tcp.settings
        scada = await asyncio.gather(*(TcpClient.connect(app.tcp.port) for _ in range(32)))
        answers = await asyncio.gather(
            *(client.read(1 + i % 2, STATE_WORD_1) for i, client in enumerate(scada)),
            return_exceptions=True,
        )
        served = sum(1 for answer in answers if answer == [STOPPED])
        assert served == 32, f"{served} of 32 served, {app.tcp.stats.refused} refused"
        assert app.tcp.stats.refused == 0
        # Another host (an engineering laptop) still gets in beside them.
        other_reader, other_writer = await open_from("127.0.0.2", app.tcp.port)
        other = TcpClient(other_reader, other_writer)
        assert await other.read(2, STATE_WORD_1) == [STOPPED]
        for client in [*scada, other]:
            await client.close()
        record_property(
            "figure:one SCADA host",
            f"32 connections from one address all served (max_connections "
            f"{settings.max_connections}, per client {settings.per_client_limit}); "
            f"another address served beside them",
        )


async def test_slow_senders_holding_every_slot_do_not_keep_a_good_client_out(
    line: SimulatedLine,
) -> None:
    async with running_gateway(config(line.path, max_connections=8)) as app:
        served = await TcpClient.connect(app.tcp.port)  # an HMI that was there first
        assert await served.read(1, STATE_WORD_1) == [STOPPED]
        stop = asyncio.Event()
        async with slow_senders(app.tcp.port, 12, stop) as reconnections:
            await eventually(lambda: len(app.tcp.stats.active) >= 8, 10.0, "every slot taken")
            # A well-behaved client arriving now connects and is served, again and again.
            for attempt in range(5):
                client = await TcpClient.connect(app.tcp.port)
                assert await client.read(2, STATE_WORD_1) == [STOPPED], attempt
                await client.close()
                await asyncio.sleep(0.2)  # the client's think time: the slow senders come back
            # The client served first was never the one evicted.
            assert await served.read(1, STATE_WORD_1) == [STOPPED]
            assert app.tcp.stats.evicted >= 5
            assert reconnections[0] >= 5
        await served.close()


async def test_writes_beyond_the_per_client_limit_get_0a_and_others_are_served(
    line: SimulatedLine,
) -> None:
    settings = {"max_queued_writes_per_client": 4, "max_requests_per_connection": 64}
    async with running_gateway(config(line.path, **settings)) as app:
        flooder = await TcpClient.connect(app.tcp.port)
        for tid in range(40):
            flooder.send(1, write_pdu(0x000B, 100 + tid), transaction_id=tid)
        answers = [await flooder.receive() for _ in range(40)]
        refused = [a for a in answers if a.pdu == bytes.fromhex("86 0A")]
        written = [a for a in answers if a.pdu[0] == 0x06]
        assert len(refused) + len(written) == 40
        assert refused, "no write was refused beyond the limit"
        assert len(written) >= 4
        assert app.tcp.stats.write_limited == len(refused)
        await flooder.close()


@pytest.mark.parametrize("unit_id", [0, 1], ids=["broadcasts", "writes"])
async def test_a_flood_of_writes_leaves_reads_their_share_of_the_line(
    line: SimulatedLine, unit_id: int
) -> None:
    settings = {"max_queued_writes_per_client": 200, "max_requests_per_connection": 200}
    gateway = config(line.path, **settings)
    gateway = gateway.model_copy(
        update={"buses": (gateway.buses[0].model_copy(update={"turnaround_ms": 50.0}),)}
    )
    async with running_gateway(gateway) as app:
        flooder = await TcpClient.connect(app.tcp.port)
        reader = await TcpClient.connect(app.tcp.port)
        flood = 120
        for tid in range(flood):  # each broadcast holds the line for its 50 ms turnaround
            flooder.send(unit_id, write_pdu(0x000B, 100 + tid % 50), transaction_id=tid)
        received = 0

        async def drain_flood() -> None:
            nonlocal received
            for _ in range(flood):
                await flooder.receive(within_s=30)
                received += 1

        draining = asyncio.create_task(drain_flood())
        # Writes still go first, but not all of them: the reader is served while the flood
        # is still queued, not after it.
        for _ in range(10):
            assert await reader.read(2, STATE_WORD_1) == [STOPPED]
        served_while_flooding = received < flood
        await draining
        assert served_while_flooding, "the reads waited for the whole flood"
        await flooder.close()
        await reader.close()
