"""Real RS-485 hardware effects, through the whole gateway: real TCP clients, a real pty line, the
simulated drives behind an adapter that behaves as common hardware does (`simulate --burst-ms`,
`--glitch`, `--echo`).

- An adapter handing bytes over in bursts every 40 ms, cutting every reply in two: with the default
  settings (char_timeout_ms 20), every reply is read whole.
- A transceiver glitch byte (00H or FFH) before every reply: skipped, counted, never trusted.
- An adapter echoing every request while the bus says `echo: false`: noticed, said once, and the
  echo is never taken for the reply (a drive's exception to a write reaches the client intact).
- All of these with 5 % of the replies spoilt: every value right.
"""

from __future__ import annotations

import asyncio
import logging
import time

import pytest

from gateway.config import GatewayConfig
from gateway.instruments.simulator import SimulatedLine
from gateway.instruments.stress.checked_load import STEADY, CheckedLoad
from gateway.profile import format_parameter
from tests.support import (
    RecordProperty,
    TcpClient,
    gateway_config,
    read_pdu,
    running_gateway,
    write_pdu,
)

RUNNING_VALUES = 0x3000
STATE_WORD_1 = 0x2100
DRIVES = [{"name": "pump1", "address": 1}, {"name": "fan2", "address": 2}]


def line_config(path: str, **bus: object) -> GatewayConfig:
    """The defaults a user starts with (response timeout 300 ms, char_timeout_ms 20), at 19200."""
    return gateway_config(path, DRIVES, baudrate=19200, timeout_ms=300, retries=2, **bus)


async def read_many(client: TcpClient, count: int, words: int) -> list[bytes]:
    return [await client.request(1 + n % 2, read_pdu(RUNNING_VALUES, words)) for n in range(count)]


def expected_running_values(line: SimulatedLine, address: int, words: int) -> bytes:
    """What the drive itself answers to the read (its running values stand still: stopped)."""
    with line.lock:
        return line.drives[address].handle(read_pdu(RUNNING_VALUES, words), time.monotonic())


async def test_replies_cut_by_40_ms_bursts_are_read_whole_with_the_defaults(
    caplog: pytest.LogCaptureFixture,
) -> None:
    with SimulatedLine(addresses=[1, 2], baudrate=19200, wire_time=True) as line:
        line.set_adapter(burst_ms=40)
        async with running_gateway(line_config(line.path)) as app:
            client = await TcpClient.connect(app.tcp.port)
            started = time.monotonic()
            answers = await read_many(client, 24, 16)
            rate = len(answers) / (time.monotonic() - started)
            await client.close()
            bus = app.buses["line1"]
            for n, answer in enumerate(answers):
                assert answer == expected_running_values(line, 1 + n % 2, 16)
            assert bus.stats.failed == bus.stats.retries == 0
            assert sum(bus.stats.bad_replies.values()) == 0
            # What the adapter did is measured and said once, with what to change.
            assert 0.015 < bus.line.longest_reply_silence_s < 0.1
        bursts = [r.getMessage() for r in caplog.records if "in bursts" in r.getMessage()]
        assert len(bursts) == 1
        assert "latency_timer" in bursts[0]
        # Each reply is late by the burst, not by a retry: about 60 ms a transaction at most.
        print(f"40 ms bursts, 16-word reads at 19200 baud: {rate:.1f} transactions/s")
        assert rate > 12


async def test_a_glitch_byte_before_every_reply_costs_nothing_but_that_byte() -> None:
    with SimulatedLine(addresses=[1, 2], baudrate=19200, wire_time=True) as line:
        for glitch in (b"\x00", b"\xff"):
            line.set_adapter(glitch=glitch)
            async with running_gateway(line_config(line.path)) as app:
                client = await TcpClient.connect(app.tcp.port)
                answers = await read_many(client, 20, 2)
                await client.close()
                bus = app.buses["line1"]
                for n, answer in enumerate(answers):
                    assert answer == expected_running_values(line, 1 + n % 2, 2)
                assert bus.stats.retries == bus.stats.failed == 0
                assert bus.line.garbage_bytes == bus.stats.transactions


async def test_a_reply_from_another_address_is_still_refused_after_a_glitch() -> None:
    with SimulatedLine(addresses=[1, 2], baudrate=19200, wire_time=True) as line:
        line.set_adapter(glitch=b"\xff")
        config = gateway_config(line.path, DRIVES, baudrate=19200, timeout_ms=100, retries=0)
        async with running_gateway(config) as app:
            line.set_line_faults(1.0, kinds=["wrong_address"], seed=1)
            client = await TcpClient.connect(app.tcp.port)
            assert await client.request(1, read_pdu(STATE_WORD_1)) == bytes.fromhex("83 0B")
            line.set_line_faults(0.0)
            assert await client.read(1, STATE_WORD_1) == [3]
            await client.close()
            assert app.buses["line1"].stats.bad_replies["address"] == 1


async def test_an_echoing_adapter_is_recognised_and_its_echo_never_taken_for_a_reply(
    caplog: pytest.LogCaptureFixture,
) -> None:
    with SimulatedLine(addresses=[1, 2], baudrate=19200, wire_time=True) as line:
        line.set_adapter(echo=True)
        async with running_gateway(line_config(line.path)) as app:
            client = await TcpClient.connect(app.tcp.port)
            # A read shows the echo for what it is (its reply differs from the request) ...
            assert await client.read(1, STATE_WORD_1) == [3]
            # ... so a write the drive refuses (P00.01 = 3 is out of range), whose echo is byte
            # for byte what a successful reply would be, gets the drive's exception, not its echo.
            refused = write_pdu(0x0001, 3)
            assert await client.request(1, refused) == bytes.fromhex("86 04")
            # A write the drive takes, and reads: each answered by the drive, not the adapter.
            assert await client.request(1, write_pdu(0x000B, 150)) == write_pdu(0x000B, 150)
            assert await client.read(1, 0x000B) == [150]
            answers = await read_many(client, 10, 2)
            await client.close()
            for n, answer in enumerate(answers):
                assert answer == expected_running_values(line, 1 + n % 2, 2)
            line_stats = app.buses["line1"].line
            assert line_stats.echo_detected
            assert line_stats.echoes == app.buses["line1"].stats.transactions
            assert app.buses["line1"].stats.retries == 0
        said = [r.getMessage() for r in caplog.records if "echoes" in r.getMessage()]
        assert len(said) == 1
        assert "set `echo: true`" in said[0]


async def test_an_echo_nobody_configured_costs_no_retries_whatever_the_register() -> None:
    """The adapter hands each byte back as it leaves the wire, so the echo arrives in pieces.
    Reads of 00xxH (the function parameters), whose echo's first bytes look like a reply with
    a byte count of 0, were taken for corrupt replies: 3 of 4 failed. Each is read at once."""
    with SimulatedLine(addresses=[1, 2], baudrate=19200, wire_time=True) as line:
        line.set_adapter(echo=True)
        async with running_gateway(line_config(line.path)) as app:
            client = await TcpClient.connect(app.tcp.port)
            expected = {}
            for address in (1, 2):
                with line.lock:
                    expected[address] = line.drives[address].handle(read_pdu(0x0003, 2), 0.0)
            answers = [await client.request(1 + n % 2, read_pdu(0x0003, 2)) for n in range(40)]
            await client.close()
            bus = app.buses["line1"]
            assert answers == [expected[1 + n % 2] for n in range(40)]
            assert bus.stats.retries == 0
            assert not bus.stats.bad_replies
            assert bus.line.echoes == bus.stats.transactions


async def test_echo_true_still_reads_the_echo_back() -> None:
    with SimulatedLine(addresses=[1, 2], baudrate=19200, wire_time=True) as line:
        line.set_adapter(echo=True)
        async with running_gateway(line_config(line.path, echo=True)) as app:
            client = await TcpClient.connect(app.tcp.port)
            assert await client.read(1, STATE_WORD_1) == [3]
            await client.close()
            assert app.buses["line1"].line.echoes == 0  # configured: nothing to say


@pytest.mark.timeout(180)
async def test_bursts_glitches_and_5_percent_line_faults_every_value_right(
    record_property: RecordProperty, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.ERROR)  # the retries' warnings are expected here
    units = [1, 2, 3, 4]
    line = SimulatedLine(addresses=units, baudrate=115200, response_delay_ms=1.0, wire_time=True)
    with line:
        line.set_adapter(burst_ms=40, glitch=b"\x00")
        line.set_line_faults(0.05, seed=20261122, late_ms=160)
        config = GatewayConfig.model_validate(
            {
                "modbus_tcp": {"host": "127.0.0.1", "port": 0},
                "buses": [
                    {
                        "name": "line1",
                        "port": line.path,
                        "baudrate": 115200,
                        "timeout_ms": 100,  # longer than a burst: the default (300) would do
                        "retries": 2,
                        "drain_ms": 150,  # a late reply (160 ms) comes inside the drain
                    }
                ],
                "drives": [{"name": f"drive{u}", "bus": "line1", "address": u} for u in units],
            }
        )
        async with running_gateway(config) as app:
            load = CheckedLoad(app.tcp.port, units, clients=8, seed=11)
            await asyncio.wait_for(load.run(asyncio.Event(), max_requests=240), 150)
            bus = app.buses["line1"]
            line_stats = line.stats
            stats = load.stats
            requests, errors = stats.requests[STEADY], stats.errors[STEADY]
            figures = (
                f"{requests} requests, {line_stats['faults_injected']} faults injected "
                f"{line_stats['faults_by_kind']}, {bus.stats.retries} retries, "
                f"{bus.line.garbage_bytes} glitch bytes skipped, {errors} errors, "
                f"{stats.wrong} wrong values"
            )
            print(f"bursts, glitches and line faults: {figures}")
            record_property("figure:real line", figures)
            assert stats.wrong == 0, stats.wrong_examples
            assert line_stats["faults_injected"] > 0
            # Errors only where the injected faults outlasted every retry: none expected at 5 %.
            assert errors <= 1, stats.exceptions
            with line.lock:
                for unit_id, register, possible in load.beliefs():
                    held = line.drives[unit_id].parameter(format_parameter(register))
                    assert possible is not None
                    assert held in possible
