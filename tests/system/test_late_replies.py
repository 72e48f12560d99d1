"""A drive slower than the response timeout: its late replies are never anybody's answer.

RTU has no transaction id: a reply that arrives after its request timed out looks exactly like
the answer to the next request of the same function and length to the same drive. Two SCADA
clients reading different registers of one slow drive got each other's registers, with no
error (40 of 80 reads at 450 ms against `timeout_ms: 300`). After a timeout the gateway now
resynchronises with the drive (a diagnostic echo carrying a fresh value) before anything else
goes to it: errors are allowed here, wrong values are not.
"""

from __future__ import annotations

import asyncio
import logging
import time

import pytest

from gateway.instruments.simulator import SimulatedLine
from tests.support import TcpClient, gateway_config, read_pdu, running_gateway

STATE_WORDS = 0x2100
RUNNING_VALUES = 0x3000
WORDS = 2  # the same function and length for both clients: their replies look alike
GATEWAY_PATH_FAILED = bytes.fromhex("83 0B")


def drive_answer(line: SimulatedLine, register: int) -> bytes:
    """What the drive itself answers to the read (it stands still: stopped, nothing changes)."""
    with line.lock:
        return line.drives[1].handle(read_pdu(register, WORDS), time.monotonic())


async def read_in_turn(port: int, register: int, count: int) -> list[bytes]:
    client = await TcpClient.connect(port)
    try:
        return [
            await client.request(1, read_pdu(register, WORDS), within_s=10) for _ in range(count)
        ]
    finally:
        await client.close()


@pytest.mark.parametrize(("delay_ms", "timeout_ms"), [(450, 300), (250, 100)])
async def test_two_clients_of_a_drive_slower_than_the_timeout_never_get_each_others_registers(
    delay_ms: int, timeout_ms: int, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.WARNING)
    with SimulatedLine(addresses=[1], baudrate=19200, response_delay_ms=delay_ms) as line:
        expected = {reg: drive_answer(line, reg) for reg in (STATE_WORDS, RUNNING_VALUES)}
        assert expected[STATE_WORDS] != expected[RUNNING_VALUES]
        config = gateway_config(
            line.path,
            [{"name": "pump1", "address": 1}],
            timeout_ms=timeout_ms,
            retries=1,
            baudrate=19200,
        )
        async with running_gateway(config) as app:
            answers = await asyncio.gather(
                read_in_turn(app.tcp.port, STATE_WORDS, 20),
                read_in_turn(app.tcp.port, RUNNING_VALUES, 20),
            )
            bus = app.buses["line1"]
            late = bus.stats.late_replies
    wrong = 0
    for register, replies in zip((STATE_WORDS, RUNNING_VALUES), answers, strict=True):
        for reply in replies:
            if reply != GATEWAY_PATH_FAILED and reply != expected[register]:
                wrong += 1
    assert wrong == 0, f"{wrong} of 40 reads got another register's values"
    # The drive did answer, late: seen, counted, and said once with what to change.
    assert late > 0
    said = [r.getMessage() for r in caplog.records if "later than" in r.getMessage()]
    assert len(said) == 1, said
    assert f"timeout_ms ({timeout_ms})" in said[0]


async def test_a_drive_that_answers_in_time_again_is_read_right_after_its_late_replies() -> None:
    """The resynchronisation ends: once the drive is quick again, every read is answered."""
    with SimulatedLine(addresses=[1], baudrate=19200, response_delay_ms=250) as line:
        expected = {reg: drive_answer(line, reg) for reg in (STATE_WORDS, RUNNING_VALUES)}
        config = gateway_config(
            line.path, [{"name": "pump1", "address": 1}], timeout_ms=100, baudrate=19200
        )
        async with running_gateway(config) as app:
            await asyncio.gather(
                read_in_turn(app.tcp.port, STATE_WORDS, 3),
                read_in_turn(app.tcp.port, RUNNING_VALUES, 3),
            )
            line.response_delay_ms = 5.0
            # Gone offline meanwhile (its requests timed out): back once a probe is answered.
            client = await TcpClient.connect(app.tcp.port)
            deadline = time.monotonic() + 30
            while await client.request(1, read_pdu(STATE_WORDS, WORDS)) != expected[STATE_WORDS]:
                assert time.monotonic() < deadline, "the drive never came back"
                await asyncio.sleep(0.2)
            await client.close()
            answers = await asyncio.gather(
                read_in_turn(app.tcp.port, STATE_WORDS, 10),
                read_in_turn(app.tcp.port, RUNNING_VALUES, 10),
            )
    assert answers[0] == [expected[STATE_WORDS]] * 10
    assert answers[1] == [expected[RUNNING_VALUES]] * 10
