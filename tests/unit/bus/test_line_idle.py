"""A request to an idle line: sent in the callback that queues it, with no pass of the event loop
for the bus's coroutine, yet never less than t3.5 after the last sound on the line; an idle bus
still closes at once. Over a real pty whose other end the test plays the drive on."""

from __future__ import annotations

import asyncio
import os
import time
import tty
from collections.abc import AsyncIterator, Iterator
from contextlib import asynccontextmanager, contextmanager

from gateway.bus.bus import Bus
from gateway.bus.dispatch import IDLE_WAKE_S
from gateway.bus.queue import Priority
from gateway.config import BusConfig
from gateway.modbus.rtu import build_frame
from gateway.settings import bus_settings
from tests.support import read_pdu

STATE_WORD_1 = 0x2100
STOPPED_REPLY = bytes.fromhex("03 02 00 03")


@contextmanager
def raw_pty() -> Iterator[tuple[int, str]]:
    """(the drive's end, the path the bus opens)."""
    master, slave = os.openpty()
    tty.setraw(slave)
    os.set_blocking(master, False)
    try:
        yield master, os.ttyname(slave)
    finally:
        os.close(master)
        os.close(slave)


@asynccontextmanager
async def idle_bus(path: str, baudrate: int) -> AsyncIterator[Bus]:
    """A bus on `path`, open and idle: its first gap over, nothing queued."""
    config = BusConfig.model_validate({"name": "line1", "port": path, "baudrate": baudrate})
    bus = Bus(bus_settings(config))
    running = asyncio.create_task(bus.run())
    try:
        assert await bus.wait_open(5.0)
        await asyncio.sleep(3 * bus.settings.line.gap_s)
        yield bus
    finally:
        bus.close()
        await asyncio.wait_for(running, 5)


def read_now(fd: int) -> bytes:
    try:
        return os.read(fd, 256)
    except BlockingIOError:
        return b""


async def test_a_request_to_an_idle_line_is_on_the_wire_as_it_is_queued() -> None:
    frame = build_frame(1, read_pdu(STATE_WORD_1))
    with raw_pty() as (drive, path):
        async with idle_bus(path, 19200) as bus:
            answer: asyncio.Future[bytes | None] = asyncio.get_running_loop().create_future()
            bus.submit(1, read_pdu(STATE_WORD_1), answer, priority=Priority.READ, client="t")
            # No await between: the frame left in `submit`'s own call, not a loop pass later.
            assert read_now(drive) == frame
            os.write(drive, build_frame(1, STOPPED_REPLY))
            assert await asyncio.wait_for(answer, 2.0) == STOPPED_REPLY
            # And again once the line is idle again: the next request goes out the same way.
            await asyncio.sleep(3 * bus.settings.line.gap_s)
            again = await asyncio.wait_for(
                asyncio.gather(
                    bus.request(1, read_pdu(STATE_WORD_1), priority=Priority.READ, client="t"),
                    answer_once(drive, frame),
                ),
                2.0,
            )
            assert again[0] == STOPPED_REPLY
            assert bus.stats.transactions == 2


async def answer_once(drive: int, frame: bytes) -> None:
    got = b""
    while len(got) < len(frame):
        got += read_now(drive)
        await asyncio.sleep(0.001)
    assert got == frame
    os.write(drive, build_frame(1, STOPPED_REPLY))


async def test_bytes_heard_on_an_idle_line_hold_the_request_a_whole_gap() -> None:
    """Noise on the idle line: a request queued right after it waits t3.5 from that noise."""
    frame = build_frame(1, read_pdu(STATE_WORD_1))
    with raw_pty() as (drive, path):
        async with idle_bus(path, 1200) as bus:
            gap_s = bus.settings.line.gap_s  # 32 ms at 1200 baud
            os.write(drive, b"\x00")
            noise_at = time.monotonic()
            while time.monotonic() < noise_at + 2.0:
                if bus.line.busy_until >= noise_at - 0.001:
                    break  # the line has heard it
                await asyncio.sleep(0.0005)
            answer: asyncio.Future[bytes | None] = asyncio.get_running_loop().create_future()
            bus.submit(1, read_pdu(STATE_WORD_1), answer, priority=Priority.READ, client="t")
            assert read_now(drive) == b""  # not at once: the noise started a gap
            got = b""
            while len(got) < len(frame) and time.monotonic() < noise_at + 2.0:
                got += read_now(drive)
                await asyncio.sleep(0.0005)
            sent_at = time.monotonic()
            assert got == frame
            assert sent_at - noise_at >= gap_s
            os.write(drive, build_frame(1, STOPPED_REPLY))
            assert await asyncio.wait_for(answer, 2.0) == STOPPED_REPLY
            assert bus.stats.min_gap_s is not None
            assert bus.stats.min_gap_s >= gap_s  # measured from the noise, never shorter


async def test_an_idle_bus_closes_at_once() -> None:
    with raw_pty() as (_, path):
        config = BusConfig.model_validate({"name": "line1", "port": path, "baudrate": 19200})
        bus = Bus(bus_settings(config))
        running = asyncio.create_task(bus.run())
        assert await bus.wait_open(5.0)
        await asyncio.sleep(0.05)  # idle, held on the gap timer until IDLE_WAKE_S
        closing_at = time.monotonic()
        bus.close()
        await asyncio.wait_for(running, 5)
        assert time.monotonic() - closing_at < IDLE_WAKE_S / 2
