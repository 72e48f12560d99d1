"""The gateway end to end: real TCP sockets, a real pty line, the simulated INVT drives."""

from __future__ import annotations

import asyncio
import struct
from pathlib import Path

import pytest

from gateway.config import GatewayConfig
from gateway.instruments.simulator import SimulatedLine
from tests.support import (
    TcpClient,
    eventually,
    gateway_config,
    read_pdu,
    running_gateway,
    write_pdu,
)
from tests.support.protocol_frames import PROTOCOL_EXCHANGES

pytestmark = pytest.mark.line(addresses=[1, 2, 3])

STATE_WORD_1 = 0x2100
IDENTIFICATION = 0x2103
STOPPED = 3


DRIVES = [
    {"name": "pump1", "address": 1},
    {"name": "fan2", "address": 2},
    {"name": "drive3", "address": 3},
]


async def test_every_protocol_frame_through_the_gateway(line: SimulatedLine) -> None:
    line.set_fault_history(3, [35] * 6)
    async with running_gateway(gateway_config(line.path, DRIVES)) as app:
        client = await TcpClient.connect(app.tcp.port)
        for request_hex, reply_hex in PROTOCOL_EXCHANGES:
            request, reply = bytes.fromhex(request_hex), bytes.fromhex(reply_hex)
            answer = await client.request(request[0], request[1:-2])
            assert answer == reply[1:-2], f"{request_hex} answered {answer.hex(' ')}"
        await client.close()


async def test_read_write_and_multiple_write_change_the_drive(line: SimulatedLine) -> None:
    async with running_gateway(gateway_config(line.path, DRIVES)) as app:
        client = await TcpClient.connect(app.tcp.port)
        # Forward run at 10.00 Hz in one 10H write, then the drive really runs.
        reply = await client.request(1, bytes.fromhex("10 20 00 00 02 04 00 01 03 E8"))
        assert reply == bytes.fromhex("10 20 00 00 02")
        assert await client.read(1, 0x2001) == [1000]

        async def running_forward() -> bool:
            return await client.read(1, STATE_WORD_1) == [1]

        await eventually(running_forward, within_s=2.0, every_s=0.02)
        # Stop (control word 5) via 06H.
        assert await client.request(1, write_pdu(0x2000, 5)) == write_pdu(0x2000, 5)
        # The other drives were never touched.
        assert await client.read(2, STATE_WORD_1) == [STOPPED]
        await client.close()


async def test_pipelined_requests_each_get_their_own_answer(line: SimulatedLine) -> None:
    async with running_gateway(gateway_config(line.path, DRIVES)) as app:
        client = await TcpClient.connect(app.tcp.port)
        # Distinct values per drive so a mixed-up answer shows.
        for unit in (1, 2, 3):
            await client.request(unit, write_pdu(0x0004, 1000 + unit))
        expected = {}
        frames = b""
        for tid in range(100, 130):
            unit = 1 + tid % 3
            expected[tid] = (unit, 1000 + unit)
            frames += struct.pack(">HHHB", tid, 0, 6, unit) + read_pdu(0x0004)
        client.writer.write(frames)  # all in one TCP segment
        answers = [await client.receive() for _ in expected]
        assert sorted(a.transaction_id for a in answers) == sorted(expected)
        for answer in answers:
            unit, value = expected[answer.transaction_id]
            assert answer.unit_id == unit
            assert answer.pdu == bytes((3, 2)) + value.to_bytes(2, "big")
        await client.close()


async def test_twenty_concurrent_clients_every_value_checked(line: SimulatedLine) -> None:
    config = gateway_config(line.path, DRIVES)
    # Twenty clients from one address: more than half of max_connections, the default limit.
    tcp = config.modbus_tcp.model_copy(update={"max_connections_per_client": 32})
    async with running_gateway(config.model_copy(update={"modbus_tcp": tcp})) as app:
        setup = await TcpClient.connect(app.tcp.port)
        for unit in (1, 2, 3):
            await setup.request(unit, write_pdu(0x0004, 2000 + unit))
            await setup.request(unit, write_pdu(0x0005, 100 + unit))

        async def client_session(index: int) -> int:
            client = await TcpClient.connect(app.tcp.port)
            checked = 0
            for round_ in range(10):
                unit = 1 + (index + round_) % 3
                assert await client.read(unit, 0x0004, 2) == [2000 + unit, 100 + unit]
                assert await client.read(unit, STATE_WORD_1) == [STOPPED]
                checked += 3
            await client.close()
            return checked

        counts = await asyncio.gather(*(client_session(i) for i in range(20)))
        assert sum(counts) == 20 * 30
        await setup.close()


async def test_unknown_unit_id_gets_0x0a(line: SimulatedLine) -> None:
    async with running_gateway(gateway_config(line.path, DRIVES)) as app:
        client = await TcpClient.connect(app.tcp.port)
        assert await client.request(99, read_pdu(STATE_WORD_1)) == bytes.fromhex("83 0A")
        # The connection is still good.
        assert await client.read(1, STATE_WORD_1) == [STOPPED]
        await client.close()


async def test_dead_drive_gets_0x0b_then_costs_no_bus_time(line: SimulatedLine) -> None:
    line.set_dead(2, True)
    config = gateway_config(line.path, DRIVES, timeout_ms=50, retries=1, offline_after=2)
    async with running_gateway(config) as app:
        client = await TcpClient.connect(app.tcp.port)
        for _ in range(2):
            assert await client.request(2, read_pdu(STATE_WORD_1)) == bytes.fromhex("83 0B")
        bus = app.buses["line1"]
        transactions = bus.stats.transactions
        loop = asyncio.get_running_loop()
        started = loop.time()
        for _ in range(20):
            assert await client.request(2, read_pdu(STATE_WORD_1)) == bytes.fromhex("83 0B")
        # Offline: answered at once, no timeouts spent, healthy drives unaffected.
        assert loop.time() - started < 0.5
        assert bus.stats.transactions - transactions <= 1  # at most one probe meanwhile
        assert await client.read(1, STATE_WORD_1) == [STOPPED]
        # Back to life: the probe finds it and requests pass again.
        line.set_dead(2, False)

        async def answered() -> bool:
            return await client.request(2, read_pdu(STATE_WORD_1)) == bytes.fromhex("03 02 00 03")

        await eventually(answered, within_s=6.0, every_s=0.1)
        await client.close()


async def test_drive_exception_reaches_the_client_intact(line: SimulatedLine) -> None:
    async with running_gateway(gateway_config(line.path, DRIVES)) as app:
        client = await TcpClient.connect(app.tcp.port)
        # P00.01 = 3 is out of range: INVT exception 04H, passed through byte-exact.
        assert await client.request(1, write_pdu(0x0001, 3)) == bytes.fromhex("86 04")
        # An unknown function code: the drive's exception 01H, not a gateway invention.
        assert await client.request(1, bytes.fromhex("2B 0E 01 00")) == bytes.fromhex("AB 01")
        assert line.stats["requests"] >= 2
        await client.close()


async def test_bad_crc_and_garbage_on_the_line_never_reach_the_client(line: SimulatedLine) -> None:
    config = gateway_config(line.path, DRIVES, retries=3)
    async with running_gateway(config) as app:
        client = await TcpClient.connect(app.tcp.port)
        await client.request(1, write_pdu(0x0004, 4321))
        line.set_line_faults(rate=0.3, kinds={"crc", "truncated", "wrong_address"}, seed=7)
        results = []
        for _ in range(60):
            results.append(await client.request(1, read_pdu(0x0004)))
            line.write_raw(b"\x55\xaa\x00\xff")  # noise between transactions
        line.set_line_faults(rate=0.0)
        good = [r for r in results if r[0] == 3]
        # Every answer is either the true value or 0x0B: never a wrong value.
        assert all(r == bytes.fromhex("03 02 10 E1") for r in good)
        assert all(r == bytes.fromhex("83 0B") for r in results if r[0] != 3)
        assert len(good) >= 55
        stats = app.buses["line1"].stats
        assert stats.retries > 0
        assert sum(stats.bad_replies.values()) > 0
        await client.close()


async def test_a_late_reply_is_never_taken_for_the_next_answer(line: SimulatedLine) -> None:
    config = gateway_config(
        line.path, DRIVES, timeout_ms=60, retries=0, drain_ms=150, char_timeout_ms=2
    )
    async with running_gateway(config) as app:
        client = await TcpClient.connect(app.tcp.port)
        line.set_reply_delay(1, 100)  # later than the 60 ms timeout
        assert await client.request(1, read_pdu(STATE_WORD_1)) == bytes.fromhex("83 0B")
        # The next answer is slow too, but in time: the late one arrives while it is awaited.
        line.set_reply_delay(1, 50)
        # Same drive, same function, same length: a late state word (0003) would pass every
        # check. The answer must be the identification code, not the late reply.
        (ident,) = await client.read(1, IDENTIFICATION)
        assert ident != STOPPED
        assert ident == line.drives[1].identification
        assert app.buses["line1"].line.discarded_bytes == 7  # the late reply, thrown away
        await client.close()


async def test_the_port_vanishing_and_coming_back(line_link: tuple[SimulatedLine, Path]) -> None:
    line, link = line_link
    config = gateway_config(str(link), DRIVES, timeout_ms=50, retries=0)
    async with running_gateway(config) as app:
        client = await TcpClient.connect(app.tcp.port)
        assert await client.read(1, STATE_WORD_1) == [STOPPED]
        changes: list[tuple[int, bool]] = []
        app.buses["line1"].add_listener(
            lambda _bus, address, online: changes.append((address, online))
        )
        line.unplug()
        assert await client.request(1, read_pdu(STATE_WORD_1)) == bytes.fromhex("83 0B")
        # The drive it had talked to is reported unreachable.
        await eventually(lambda: (1, False) in changes, within_s=2.0)
        line.replug()  # a new pty, the same by-id style link

        async def answered() -> bool:
            return await client.request(1, read_pdu(STATE_WORD_1)) == bytes.fromhex("03 02 00 03")

        await eventually(answered, within_s=10.0, every_s=0.1)
        assert app.buses["line1"].stats.reopens >= 1
        assert changes[-1] == (1, True)  # found again by its probe
        await client.close()


async def test_malformed_header_closes_only_that_connection(line: SimulatedLine) -> None:
    async with running_gateway(gateway_config(line.path, DRIVES)) as app:
        good = await TcpClient.connect(app.tcp.port)
        bad = await TcpClient.connect(app.tcp.port)
        bad.writer.write(bytes.fromhex("00 01 00 07 00 06 01 03 21 00 00 01"))  # protocol id 7
        assert await asyncio.wait_for(bad.reader.read(100), 5) == b""  # closed by the gateway
        assert await good.read(1, STATE_WORD_1) == [STOPPED]
        await good.close()
        await bad.close()


async def test_broadcast_write_reaches_every_drive_and_is_echoed(line: SimulatedLine) -> None:
    async with running_gateway(gateway_config(line.path, DRIVES, turnaround_ms=20)) as app:
        client = await TcpClient.connect(app.tcp.port)
        assert await client.request(0, write_pdu(0x0005, 777)) == write_pdu(0x0005, 777)
        for unit in (1, 2, 3):
            assert await client.read(unit, 0x0005) == [777]
        # A read can't be broadcast: nothing would answer it.
        assert await client.request(0, read_pdu(0x0005)) == bytes.fromhex("83 0A")
        await client.close()


async def test_two_buses_in_one_service_run_independently() -> None:
    with (
        SimulatedLine(addresses=[1, 2], baudrate=115200) as line_a,
        SimulatedLine(addresses=[1], baudrate=9600) as line_b,
    ):
        config = GatewayConfig.model_validate(
            {
                "modbus_tcp": {"host": "127.0.0.1", "port": 0},
                "buses": [
                    {"name": "a", "port": line_a.path, "baudrate": 115200, "timeout_ms": 100},
                    {"name": "b", "port": line_b.path, "baudrate": 9600, "timeout_ms": 100},
                ],
                "drives": [
                    {"name": "a1", "bus": "a", "address": 1},
                    {"name": "a2", "bus": "a", "address": 2, "timeout_ms": 1500, "retries": 0},
                    {"name": "b1", "bus": "b", "address": 1, "unit_id": 11},
                ],
            }
        )
        async with running_gateway(config) as app:
            client = await TcpClient.connect(app.tcp.port)
            # The same address on two lines is two drives, told apart by unit id.
            await client.request(1, write_pdu(0x0005, 111))
            await client.request(11, write_pdu(0x0005, 222))
            assert await client.read(1, 0x0005) == [111]
            assert await client.read(11, 0x0005) == [222]
            # A dead drive holds line a for its own 1.5 s timeout (no retries) ...
            line_a.set_dead(2, True)
            dead = asyncio.create_task(client.request(2, read_pdu(STATE_WORD_1)))
            await eventually(lambda: line_a.stats["ignored"], what="the request on line a")
            # ... while line b answers in the meantime.
            other = await TcpClient.connect(app.tcp.port)
            assert await other.read(11, STATE_WORD_1) == [STOPPED]
            assert not dead.done()
            assert await dead == bytes.fromhex("83 0B")
            assert app.buses["a"].stats.timeouts == 1  # the drive's retries: 0 overrides the bus's
            assert app.buses["b"].stats.timeouts == 0
            await client.close()
            await other.close()


async def test_idle_clients_are_closed_and_extra_connections_refused(
    line: SimulatedLine,
) -> None:
    config = GatewayConfig.model_validate(
        {
            "modbus_tcp": {
                "host": "127.0.0.1",
                "port": 0,
                "max_connections": 2,
                "max_connections_per_client": 2,
                # Long enough that first and second, each just served, are still open when the
                # third knocks, even on a busy machine that stalls this process a while.
                "idle_timeout_s": 2.0,
            },
            "buses": [{"name": "line1", "port": line.path, "baudrate": 115200}],
            "drives": [{"name": "pump1", "bus": "line1", "address": 1}],
        }
    )
    async with running_gateway(config) as app:
        first = await TcpClient.connect(app.tcp.port)
        second = await TcpClient.connect(app.tcp.port)
        assert await first.read(1, STATE_WORD_1) == [STOPPED]
        assert await second.read(1, STATE_WORD_1) == [STOPPED]  # both served: none evicted
        third = await TcpClient.connect(app.tcp.port)
        assert await asyncio.wait_for(third.reader.read(100), 15) == b""  # refused: closed at once
        assert app.tcp.stats.refused == 1
        assert await second.read(1, STATE_WORD_1) == [STOPPED]  # the others keep working
        # Silent for longer than idle_timeout_s: closed by the gateway.
        assert await asyncio.wait_for(first.reader.read(100), 15) == b""
        assert app.tcp.stats.idle_closed >= 1
        assert app.tcp.stats.refused == 1
        for client in (first, second, third):
            await client.close()


async def test_read_only_lets_only_reads_through(line: SimulatedLine) -> None:
    config = GatewayConfig.model_validate(
        {
            "modbus_tcp": {"host": "127.0.0.1", "port": 0, "read_only": True},
            "buses": [{"name": "line1", "port": line.path, "baudrate": 115200}],
            "drives": [{"name": "pump1", "bus": "line1", "address": 1}],
        }
    )
    async with running_gateway(config) as app:
        client = await TcpClient.connect(app.tcp.port)
        assert await client.read(1, STATE_WORD_1) == [STOPPED]
        loopback = bytes.fromhex("08 00 00 12 AB")
        assert await client.request(1, loopback) == loopback
        assert await client.request(1, write_pdu(0x2000, 1)) == bytes.fromhex("86 01")
        # 08H sub-function 0001 restarts communications: not a read.
        assert await client.request(1, bytes.fromhex("08 00 01 00 00")) == bytes.fromhex("88 01")
        assert await client.request(1, bytes.fromhex("41 00")) == bytes.fromhex("C1 01")  # vendor
        assert await client.read(1, STATE_WORD_1) == [STOPPED]  # the run never reached it
        assert app.tcp.stats.denied == 3
        await client.close()
