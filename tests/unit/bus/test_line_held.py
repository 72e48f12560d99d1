"""Back-to-back transactions carried by the line's own callbacks: while requests keep coming,
the port's reader callback takes each whole reply, keeps the gap and sends the next frame, and
the caller (the bus's coroutine) is not woken in between; a reply that is not plainly whole and
valid goes back to the caller's own reading. Over a real pty with simulated drives."""

from __future__ import annotations

import asyncio
from collections import deque

import pytest

from gateway.bus.line import Exchange, Sending, SerialLine
from gateway.config import BusConfig
from gateway.errors import ReplyTimeout
from gateway.instruments.simulator import SimulatedLine
from gateway.modbus.rtu import build_frame
from gateway.modbus.timing import FAST_T35_S
from gateway.settings import bus_settings
from tests.support import read_pdu

STATE_WORD_1 = 0x2100
STOPPED_REPLY = bytes.fromhex("03 02 00 03")
SILENT = 9

pytestmark = pytest.mark.line(addresses=[1, 2])


def open_line(path: str) -> SerialLine:
    config = BusConfig.model_validate({"name": "line1", "port": path, "baudrate": 115200})
    line = SerialLine(bus_settings(config).line)
    line.open()
    return line


async def test_the_caller_stays_held_while_the_reader_callback_carries_each_transaction(
    line: SimulatedLine,
) -> None:
    frames = deque(build_frame(1 + n % 2, read_pdu(STATE_WORD_1)) for n in range(10))
    replied: list[tuple[Sending, Exchange]] = []
    serial = open_line(line.path)
    try:
        # Every frame but the first is picked in a callback, after the reply before it.
        ended = await asyncio.wait_for(
            serial.send_after_gap(
                lambda: frames.popleft() if frames else None,
                lambda: 0.5,
                lambda sending, exchange: replied.append((sending, exchange)),
            ),
            5.0,
        )
    finally:
        serial.close()
    assert ended is None  # back only once nothing was left to send
    assert [exchange.reply_pdu for _, exchange in replied] == [STOPPED_REPLY] * 10
    assert [sending.frame[0] for sending, _ in replied] == [1, 2] * 5  # in the order picked
    assert line.stats["requests"] == 10
    # Each frame after the first waited a whole t3.5 after the reply before it.
    assert all(exchange.gap_s >= FAST_T35_S for _, exchange in replied[1:])
    assert line.stats["gap_violations"] == 0


@pytest.mark.line(addresses=[1])
async def test_a_reply_that_never_comes_goes_back_to_the_callers_own_reading(
    line: SimulatedLine,
) -> None:
    frames = deque(
        [build_frame(1, read_pdu(STATE_WORD_1)), build_frame(SILENT, read_pdu(STATE_WORD_1))]
    )
    replied: list[bytes | None] = []
    serial = open_line(line.path)
    try:
        waiting = await asyncio.wait_for(
            serial.send_after_gap(
                lambda: frames.popleft() if frames else None,
                lambda: 0.05,
                lambda _, exchange: replied.append(exchange.reply_pdu),
            ),
            5.0,
        )
        assert replied == [STOPPED_REPLY]  # the first, carried by the callback
        assert waiting is not None  # the second is the caller's
        assert waiting.frame[0] == SILENT
        with pytest.raises(ReplyTimeout):
            await serial.finish(waiting, expect_reply=True, timeout_s=0.05)
    finally:
        serial.close()
