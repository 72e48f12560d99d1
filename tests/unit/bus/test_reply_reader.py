"""The rest of an attempt read by its caller (`ReplyReader`, through `SerialLine.transact` and
`finish`): a reply delivered in bursts read whole by its length, one that stops short failed at
the response deadline and not before, a silent drive's late reply caught by the drain and set
aside, another drive's frame set aside before the reply, a corrupt reply, a frame answering an
owed request never taken for the answer, a broadcast's turnaround. Over a raw pty whose other
end the test plays the drive on."""

from __future__ import annotations

import asyncio
import os
import time
import tty
from collections.abc import AsyncIterator, Iterator
from contextlib import asynccontextmanager, contextmanager

import pytest

from gateway.bus.line import SerialLine
from gateway.config import BusConfig
from gateway.errors import BadReply, ReplyTimeout
from gateway.modbus.rtu import build_frame
from gateway.settings import bus_settings
from tests.support import read_pdu, write_pdu
from tests.unit.bus.line_users import send_after_gap

REQUEST = build_frame(1, read_pdu(0x2100))
STOPPED_REPLY = bytes.fromhex("03 02 00 03")
REPLY = build_frame(1, STOPPED_REPLY)
TIMEOUT_S = 0.1
CHAR_TIMEOUT_S = 0.02  # the bus's default char_timeout_ms
DRAIN_S = 0.05  # the bus's default drain_ms


@contextmanager
def raw_pty() -> Iterator[tuple[int, str]]:
    """(the drive's end, the path the line opens)."""
    master, slave = os.openpty()
    tty.setraw(slave)
    os.set_blocking(master, False)
    try:
        yield master, os.ttyname(slave)
    finally:
        os.close(master)
        os.close(slave)


@asynccontextmanager
async def line_and_drive(**bus: object) -> AsyncIterator[tuple[SerialLine, int]]:
    with raw_pty() as (drive, path):
        config = BusConfig.model_validate({"name": "line1", "port": path, "baudrate": 19200, **bus})
        line = SerialLine(bus_settings(config).line)
        line.open()
        assert line.settings.char_timeout_s == CHAR_TIMEOUT_S
        assert line.settings.drain_s == DRAIN_S
        try:
            yield line, drive
        finally:
            line.close()


async def request_heard(drive: int, frame: bytes = REQUEST) -> None:
    """Wait until `frame` has reached the drive's end."""
    got = b""
    deadline = time.monotonic() + 2.0
    while len(got) < len(frame):
        assert time.monotonic() < deadline, "the request never came"
        try:
            got += os.read(drive, 256)
        except BlockingIOError:
            await asyncio.sleep(0.0005)
    assert got == frame


async def test_a_reply_delivered_in_bursts_is_read_whole_by_its_length() -> None:
    """A pause inside a reply longer than the character timeout (an adapter's latency timer)
    does not end a reply whose length its header gives."""
    async with line_and_drive() as (line, drive):
        attempt = asyncio.ensure_future(line.transact(REQUEST, expect_reply=True, timeout_s=0.5))
        await request_heard(drive)
        os.write(drive, REPLY[:3])
        await asyncio.sleep(2 * CHAR_TIMEOUT_S)
        os.write(drive, REPLY[3:])
        exchange = await asyncio.wait_for(attempt, 2.0)
    assert exchange.reply_pdu == STOPPED_REPLY
    assert exchange.strays == ()
    assert line.longest_reply_silence_s >= CHAR_TIMEOUT_S


async def test_a_reply_that_stops_short_fails_at_the_response_deadline_not_before() -> None:
    async with line_and_drive() as (line, drive):
        began = time.monotonic()
        attempt = asyncio.ensure_future(
            line.transact(REQUEST, expect_reply=True, timeout_s=TIMEOUT_S)
        )
        await request_heard(drive)
        os.write(drive, REPLY[:5])
        with pytest.raises(BadReply) as failed:
            await asyncio.wait_for(attempt, 2.0)
        took_s = time.monotonic() - began
    assert failed.value.kind == "truncated"
    assert failed.value.frame == REPLY[:5]
    assert took_s >= TIMEOUT_S


async def test_a_silent_drives_late_reply_is_caught_by_the_drain_and_set_aside() -> None:
    """The reply comes after the response timeout, within the drain: never the answer (the
    attempt timed out), but set aside for the ledger, so the next request doesn't take it."""
    async with line_and_drive() as (line, drive):
        attempt = asyncio.ensure_future(
            line.transact(REQUEST, expect_reply=True, timeout_s=TIMEOUT_S)
        )
        await request_heard(drive)
        await asyncio.sleep(TIMEOUT_S + DRAIN_S / 2)  # in the middle of the drain
        os.write(drive, REPLY)
        with pytest.raises(ReplyTimeout) as failed:
            await asyncio.wait_for(attempt, 2.0)
        # Nothing of it left for the next attempt to find.
        attempt = asyncio.ensure_future(line.transact(REQUEST, expect_reply=True, timeout_s=0.5))
        await request_heard(drive)
        other = build_frame(1, bytes.fromhex("03 02 00 01"))
        os.write(drive, other)
        assert (await asyncio.wait_for(attempt, 2.0)).reply_pdu == other[1:-2]
    ((stray, heard_at),) = failed.value.strays
    assert stray == REPLY
    assert heard_at > 0


async def test_another_drives_frame_before_the_reply_is_set_aside_and_the_reply_taken() -> None:
    foreign = build_frame(2, bytes.fromhex("03 02 00 01"))
    async with line_and_drive() as (line, drive):
        attempt = asyncio.ensure_future(line.transact(REQUEST, expect_reply=True, timeout_s=0.5))
        await request_heard(drive)
        os.write(drive, foreign)
        await asyncio.sleep(0.005)
        os.write(drive, REPLY)
        exchange = await asyncio.wait_for(attempt, 2.0)
    assert exchange.reply_pdu == STOPPED_REPLY
    assert [frame for frame, _ in exchange.strays] == [foreign]


async def test_a_frame_that_answers_an_owed_request_is_never_the_answer() -> None:
    """The drive still owes a reply to an older request alike: a frame that may be that one's
    is set aside, and the wait goes on for a reply that can only be this request's."""
    older = build_frame(1, read_pdu(0x2100, 2))
    owed_reply = build_frame(1, bytes.fromhex("03 04 00 03 00 00"))
    ours = build_frame(1, read_pdu(0x2100))
    async with line_and_drive() as (line, drive):
        sending = await send_after_gap(line, lambda: ours)
        assert sending is not None
        attempt = asyncio.ensure_future(
            line.finish(sending, expect_reply=True, timeout_s=0.5, owed=(older,))
        )
        await request_heard(drive, ours)
        os.write(drive, owed_reply)
        await asyncio.sleep(0.005)
        os.write(drive, REPLY)
        exchange = await asyncio.wait_for(attempt, 2.0)
    assert exchange.reply_pdu == STOPPED_REPLY
    assert [frame for frame, _ in exchange.strays] == [owed_reply]


async def test_a_corrupt_reply_fails_and_leaves_the_line_clean_for_the_next() -> None:
    corrupt = REPLY[:-1] + bytes((REPLY[-1] ^ 0xFF,))
    async with line_and_drive() as (line, drive):
        attempt = asyncio.ensure_future(line.transact(REQUEST, expect_reply=True, timeout_s=0.5))
        await request_heard(drive)
        os.write(drive, corrupt + b"\x00")  # and a byte behind it
        with pytest.raises(BadReply) as failed:
            await asyncio.wait_for(attempt, 2.0)
        attempt = asyncio.ensure_future(line.transact(REQUEST, expect_reply=True, timeout_s=0.5))
        await request_heard(drive)
        os.write(drive, REPLY)
        assert (await asyncio.wait_for(attempt, 2.0)).reply_pdu == STOPPED_REPLY
    assert failed.value.kind == "crc"


async def test_a_broadcast_holds_the_line_for_the_drives_turnaround() -> None:
    broadcast = build_frame(0, write_pdu(0x2001, 2500))
    async with line_and_drive(turnaround_ms=50) as (line, drive):
        exchange = await asyncio.wait_for(
            line.transact(broadcast, expect_reply=False, timeout_s=TIMEOUT_S), 2.0
        )
        await request_heard(drive, broadcast)
        sent = line.busy_until - line.settings.turnaround_s
        assert exchange.reply_pdu is None
        assert exchange.busy_s >= 0.05
        # The next frame waits for the turnaround's end and its gap after it.
        following = await asyncio.wait_for(send_after_gap(line, lambda: REQUEST), 2.0)
    assert following is not None
    assert following.started >= sent + 0.05 + line.settings.gap_s
