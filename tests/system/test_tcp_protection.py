"""One Modbus-TCP client cannot starve the others: a flood of pipelined requests, a client that
never reads its answers, one that stops halfway through a frame, one connection too many.

Real sockets against the gateway on a simulated line at 115200 baud with wire time, where one
transaction takes 2-3 ms: a well-behaved client's reads must stay that order of fast throughout.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import struct
import time

import pytest

from gateway.instruments.simulator import SimulatedLine
from tests.support import (
    RecordProperty,
    TcpClient,
    eventually,
    protected_config,
    read_pdu,
    running_gateway,
)

STATE_WORD_1 = 0x2100
STOPPED = 3
SLOW_S = 0.25
"""A read slower than this while another client misbehaves means it was starved."""


async def timed_reads(port: int, until: asyncio.Event, unit_id: int = 2) -> list[float]:
    """A well-behaved SCADA client: one read at a time until `until`; each one's latency."""
    client = await TcpClient.connect(port)
    latencies = []
    try:
        while not until.is_set():
            started = time.monotonic()
            assert await client.read(unit_id, STATE_WORD_1) == [STOPPED]
            latencies.append(time.monotonic() - started)
    finally:
        await client.close()
    return latencies


def flood_requests(count: int) -> list[tuple[int, bytes]]:
    """Distinct reads (identical ones would share one bus transaction and load nothing)."""
    registers = [0x0003, 0x0004, 0x0005, 0x000A, 0x000B, 0x2100, 0x2101, 0x3000, 0x3001]
    return [(tid, read_pdu(registers[tid % len(registers)], 1 + tid % 3)) for tid in range(count)]


async def test_a_flood_of_pipelined_requests_does_not_starve_another_client(
    line: SimulatedLine, record_property: RecordProperty
) -> None:
    async with running_gateway(protected_config(line.path)) as app:
        flooder = await TcpClient.connect(app.tcp.port)
        requests = flood_requests(400)
        done = asyncio.Event()
        reader = asyncio.create_task(timed_reads(app.tcp.port, done))
        for tid, pdu in requests:  # all at once: one burst of 400 frames
            flooder.send(1, pdu, transaction_id=tid)
        answered: dict[int, bytes] = {}
        try:
            while len(answered) < len(requests):
                reply = await flooder.receive(within_s=10)
                assert reply.transaction_id not in answered
                answered[reply.transaction_id] = reply.pdu
        finally:
            done.set()
            latencies = await reader
            await flooder.close()
        # Every flood request got its own answer (none an exception: the drive is healthy)...
        assert all(not pdu[0] & 0x80 for pdu in answered.values())
        assert sorted(answered) == [tid for tid, _ in requests]
        # ...and meanwhile the other client kept its turn on the line, read after read.
        assert len(latencies) >= 20, latencies
        assert max(latencies) < SLOW_S, max(latencies)
        record_property(
            "figure:flood",
            f"400 pipelined requests all answered; meanwhile another client made "
            f"{len(latencies)} reads, the slowest {max(latencies) * 1000:.1f} ms",
        )


async def test_a_client_that_never_reads_is_not_read_either(
    line: SimulatedLine, record_property: RecordProperty
) -> None:
    async with running_gateway(protected_config(line.path, idle_timeout_s=1.0)) as app:
        hog = socket.socket()
        hog.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        hog.connect(("127.0.0.1", app.tcp.port))
        hog.setblocking(False)
        # Requests for an unknown unit id are answered at once (0AH, no bus): the fastest way
        # to produce answers the hog doesn't read.
        burst = (struct.pack(">HHHB", 7, 0, 6, 99) + read_pdu(STATE_WORD_1)) * 2000
        done = asyncio.Event()
        reader = asyncio.create_task(timed_reads(app.tcp.port, done))
        try:
            stalled_since = None
            deadline = time.monotonic() + 10
            while time.monotonic() < deadline:
                try:
                    hog.send(burst)
                    stalled_since = None
                except BlockingIOError:
                    stalled_since = stalled_since or time.monotonic()
                    if time.monotonic() - stalled_since > 0.3:
                        break  # the gateway stopped taking its requests
                await asyncio.sleep(0.001)  # the hog's own pace
            else:
                pytest.fail("the gateway kept reading a client that never reads its answers")
            requests_when_stalled = app.tcp.stats.requests
            await asyncio.sleep(0.3)  # asserting an absence: a window the hog would be read in
            assert app.tcp.stats.requests - requests_when_stalled < 50  # only the other client's
            # What the gateway holds for the hog: its write buffer, near the 64 KiB high-water.
            buffered = sum(
                c._transport.get_write_buffer_size()
                for c in app.tcp._connections
                if c._transport is not None
            )
            assert buffered < 128 * 1024
            # Silent (the gateway isn't reading it) for idle_timeout_s: closed, its slot freed.
            await eventually(
                lambda: app.tcp.stats.idle_closed >= 1 and len(app.tcp.stats.active) == 1,
                within_s=3.0,
                what="the hog closed after idle_timeout_s",
            )
        finally:
            done.set()
            latencies = await reader
            hog.close()
        assert max(latencies) < SLOW_S, max(latencies)
        record_property(
            "figure:client that never reads",
            f"no more read after {requests_when_stalled} requests, {buffered} bytes of answers "
            f"held, closed when idle; another client's slowest read {max(latencies) * 1000:.1f} ms",
        )


async def test_a_client_stuck_halfway_through_a_frame_is_closed(
    line: SimulatedLine, record_property: RecordProperty
) -> None:
    async with running_gateway(protected_config(line.path, idle_timeout_s=1.0)) as app:
        stuck_reader, stuck = await asyncio.open_connection("127.0.0.1", app.tcp.port)
        stuck.write(struct.pack(">HHHB", 1, 0, 6, 1) + b"\x03\x21")  # 3 of the PDU's 5 bytes
        done = asyncio.Event()
        reader = asyncio.create_task(timed_reads(app.tcp.port, done))
        try:
            started = time.monotonic()
            assert await asyncio.wait_for(stuck_reader.read(), 5) == b""  # closed by the gateway
            closed_after = time.monotonic() - started
        finally:
            done.set()
            latencies = await reader
            stuck.close()
        assert 0.9 < closed_after < 2.5
        assert app.tcp.stats.idle_closed == 1
        assert max(latencies) < SLOW_S
        record_property(
            "figure:half a frame",
            f"closed after {closed_after:.2f} s (idle_timeout_s 1); another client's slowest "
            f"read {max(latencies) * 1000:.1f} ms",
        )


async def test_one_connection_too_many_is_refused_while_the_others_work(
    line: SimulatedLine,
) -> None:
    config = protected_config(line.path, max_connections=3, max_connections_per_client=3)
    async with running_gateway(config) as app:
        clients = [await TcpClient.connect(app.tcp.port) for _ in range(3)]
        try:
            for client in clients:  # served: none of them may be evicted for a newcomer
                assert await client.read(1, STATE_WORD_1) == [STOPPED]
            extra_reader, extra = await asyncio.open_connection("127.0.0.1", app.tcp.port)
            assert await asyncio.wait_for(extra_reader.read(), 2) == b""  # closed at once
            extra.close()
            assert app.tcp.stats.refused == 1
            for client in clients:
                assert await client.read(1, STATE_WORD_1) == [STOPPED]
            # A slot that frees up is taken by the next client.
            await clients.pop().close()
            await eventually(lambda: len(app.tcp.stats.active) == len(clients), what="slot free")
            clients.append(await TcpClient.connect(app.tcp.port))
            assert await clients[-1].read(2, STATE_WORD_1) == [STOPPED]
            assert app.tcp.stats.refused == 1
        finally:
            for client in clients:
                with contextlib.suppress(Exception):
                    await client.close()
