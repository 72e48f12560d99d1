"""The line tells the truth: a reply reaches a client only when it can be nothing but the answer.

RTU frames carry no transaction id. A drive later than the response timeout answers after the
gateway has moved on: to its neighbour, whose reply may still be coming. And a device built on
libmodbus frames only the function codes it knows, so a diagnostic echo (08H) gets no answer at
all from it. The ledger of what each drive owes (`gateway.bus.late_replies`) and its markers are
tried here as a plant's line meets them: wrong values are never allowed, errors are.
"""

from __future__ import annotations

import asyncio
import time

import pytest

from gateway.instruments.simulator import SimulatedLine
from tests.support import TcpClient, gateway_config, read_pdu, running_gateway

STATE_WORDS = 0x2100
RUNNING_VALUES = 0x3000
WORDS = 2  # the same function and length for every read: replies look alike
ONLY_WHAT_LIBMODBUS_FRAMES = {0x03, 0x04, 0x06, 0x10}


def drive_answer(line: SimulatedLine, address: int, register: int) -> bytes:
    """What the (stopped, unchanging) drive itself answers to the read."""
    with line.lock:
        return line.drives[address].handle(read_pdu(register, WORDS), time.monotonic())


async def read_until(
    port: int, unit: int, register: int, until: float
) -> list[tuple[float, bytes]]:
    """Read in a loop until `until` (monotonic): (when asked, the reply) each time."""
    client = await TcpClient.connect(port)
    replies = []
    try:
        while (asked := time.monotonic()) < until:
            replies.append((asked, await client.request(unit, read_pdu(register, WORDS), 10)))
            await asyncio.sleep(0.01)
    finally:
        await client.close()
    return replies


@pytest.mark.parametrize("retries", [0, 1, 2])
@pytest.mark.parametrize("neighbour_ms", [10, 30, 100])
async def test_a_drive_later_than_the_timeout_never_shifts_its_neighbour_one_reply_late(
    neighbour_ms: int, retries: int
) -> None:
    """Drive 1 answers in 375 ms against the default 300 ms; drive 2 is healthy but not instant.
    Drive 1's late replies land in drive 2's windows: they are set aside, and drive 2's own reply
    is still waited for (it used to end the attempt, and drive 2 stayed one reply late)."""
    with SimulatedLine(addresses=[1, 2], baudrate=19200) as line:
        line.set_reply_delay(1, 370)  # and its 5 ms response delay: 375 ms
        line.set_reply_delay(2, neighbour_ms - 5)
        expected = {reg: drive_answer(line, 2, reg) for reg in (STATE_WORDS, RUNNING_VALUES)}
        assert expected[STATE_WORDS] != expected[RUNNING_VALUES]
        config = gateway_config(
            line.path,
            [{"name": "slow", "address": 1}, {"name": "neighbour", "address": 2}],
            baudrate=19200,
            timeout_ms=300,
            retries=retries,
        )
        async with running_gateway(config) as app:
            until = time.monotonic() + 4.0
            _, state, running = await asyncio.gather(
                read_until(app.tcp.port, 1, STATE_WORDS, until),
                read_until(app.tcp.port, 2, STATE_WORDS, until),
                read_until(app.tcp.port, 2, RUNNING_VALUES, until),
            )
            late = app.buses["line1"].drive_stats[1].late_replies
    wrong = [
        reply.hex(" ")
        for register, replies in ((STATE_WORDS, state), (RUNNING_VALUES, running))
        for _, reply in replies
        if reply != expected[register] and reply[1:] != b"\x0b"
    ]
    good = sum(
        reply == expected[r]
        for r, rs in ((STATE_WORDS, state), (RUNNING_VALUES, running))
        for _, reply in rs
    )
    assert not wrong, (
        f"{len(wrong)} of drive 2's reads got another request's registers: {wrong[:4]}"
    )
    assert good >= 10, f"drive 2 was hardly served: {good} good reads"
    assert late > 0  # drive 1 did answer, late: set aside, counted


@pytest.mark.parametrize("stall_s", [0.4, 0.8, 3.0])
async def test_a_device_that_knows_only_reads_and_writes_is_back_within_a_second_of_a_stall(
    stall_s: float,
) -> None:
    """A device that frames only 03H/04H/06H/10H stays silent to 08H: after a stall it is
    brought back in step with reads, never with an echo it can't answer."""
    with SimulatedLine(addresses=[1], baudrate=19200) as line:
        line.know_only(1, ONLY_WHAT_LIBMODBUS_FRAMES)
        expected = drive_answer(line, 1, STATE_WORDS)
        config = gateway_config(
            line.path, [{"name": "meter", "address": 1}], baudrate=19200, timeout_ms=300, retries=2
        )
        async with running_gateway(config) as app:
            start = time.monotonic()
            reading = asyncio.create_task(
                read_until(app.tcp.port, 1, STATE_WORDS, start + 3 + stall_s + 3)
            )
            await asyncio.sleep(1.0)
            line.stall(1, stall_s)
            stall_ends = time.monotonic() + stall_s
            replies = await reading
            stats = app.buses["line1"].drive_stats[1]
            # The stall was felt (a short one is caught by a retry of the same request, a
            # longer one needs markers: reads, never the echo it can't answer).
            assert stats.timeouts > 0
    wrong = [reply for _, reply in replies if reply != expected and reply[1:] != b"\x0b"]
    assert not wrong, wrong
    after = [(asked, reply) for asked, reply in replies if asked >= stall_ends]
    first_good = next(asked for asked, reply in after if reply == expected)
    assert first_good - stall_ends < 1.0, f"first good reply {first_good - stall_ends:.2f} s after"
    settled = [reply for asked, reply in after if asked >= stall_ends + 1.0]
    assert settled
    assert all(reply == expected for reply in settled), settled
