"""The inter-frame gap, kept by the line's `GapKeeper` (reached through `SerialLine`, which puts
it together with the port and the receiver): no frame leaves before t3.5 of silence after the
last byte heard, bytes heard during the gap start it again, the frame is chosen at the gap's end,
and an idle caller's next frame goes in the very call that queues it. Over a raw pty whose other
end the test plays the drive on, every time measured at that end."""

from __future__ import annotations

import asyncio
import os
import time
import tty
from collections import deque
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from gateway.bus.gap_lead import MAX_LEAD_S
from gateway.bus.line import Sending, SerialLine
from gateway.config import BusConfig
from gateway.modbus.rtu import build_frame
from gateway.modbus.timing import CharacterFormat
from gateway.settings import bus_settings
from tests.support import eventually, read_pdu
from tests.unit.bus.line_users import send_after_gap

STATE_WORD_1 = 0x2100
REQUEST = build_frame(1, read_pdu(STATE_WORD_1))
STOPPED_REPLY = bytes.fromhex("03 02 00 03")
BAUDRATE = 1200
GAP_S = CharacterFormat(BAUDRATE, "E", 1).t35_s
"""t3.5 at 1200 baud 8E1: 32 ms, long enough to put bytes inside it from a loop callback."""


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


def open_line(path: str) -> SerialLine:
    config = BusConfig.model_validate({"name": "line1", "port": path, "baudrate": BAUDRATE})
    line = SerialLine(bus_settings(config).line)
    line.open()
    assert line.settings.gap_s == GAP_S  # t3.5 when the configuration sets no gap of its own
    return line


class Drive:
    """The pty's far end: every request that reaches it and when (read in a reader callback
    of the test's loop), every write of its own and when; answers each request at once when
    given an `answer`."""

    def __init__(self, fd: int, answer: Callable[[int], bytes | None] | None = None) -> None:
        self.fd = fd
        self.requests: list[tuple[float, bytes]] = []
        """Each whole request (8 bytes: the tests send reads only), when its last byte came."""
        self.wrote: list[float] = []
        """When each write of the drive's was done (its bytes on their way to the line)."""
        self._answer = answer
        self._partial = b""
        asyncio.get_running_loop().add_reader(fd, self.read)

    def close(self) -> None:
        asyncio.get_running_loop().remove_reader(self.fd)

    def read(self) -> None:
        try:
            data = os.read(self.fd, 256)
        except BlockingIOError:
            return
        now = time.monotonic()
        self._partial += data
        while len(self._partial) >= len(REQUEST):
            request, self._partial = self._partial[:8], self._partial[8:]
            self.requests.append((now, request))
            reply = self._answer(len(self.requests)) if self._answer is not None else None
            if reply is not None:
                self.write(reply)

    def write(self, data: bytes) -> None:
        os.write(self.fd, data)
        self.wrote.append(time.monotonic())

    def make_noise(self) -> None:
        """A byte of noise, from a callback of its own: what came before it is read first, so
        a request already on its way is known for one that came before the noise."""
        self.read()
        self.write(b"\xff")


def picking(frames: deque[bytes], picked_at: list[float]) -> Callable[[], bytes | None]:
    """`Dispatch.pick` for these tests: the next frame, until there is none; when asked."""

    def pick() -> bytes | None:
        picked_at.append(time.monotonic())
        return frames.popleft() if frames else None

    return pick


async def test_a_frame_leaves_a_whole_gap_after_the_last_byte_heard_and_is_chosen_at_its_end() -> (
    None
):
    with raw_pty() as (master, path):
        line = open_line(path)
        drive = Drive(master)
        try:
            await asyncio.sleep(2 * GAP_S)  # the gap after opening is over: the line idle
            drive.make_noise()
            noise_at = drive.wrote[-1]
            await eventually(lambda: line.busy_until >= noise_at, what="the noise heard")
            picked_at: list[float] = []
            sending = await asyncio.wait_for(
                send_after_gap(line, picking(deque([REQUEST]), picked_at)), 2.0
            )
            assert sending is not None
            await eventually(lambda: drive.requests, what="the request at the drive")
        finally:
            drive.close()
            line.close()
    ((arrived, request),) = drive.requests
    assert request == REQUEST
    assert arrived - noise_at >= GAP_S  # on the wire: never inside the gap
    assert sending.gap_s >= GAP_S  # and the line says so too
    # Chosen at the gap's end (a wake-up at most a lead early), not as the caller began.
    assert picked_at == [picked_at[0]]
    assert picked_at[0] >= noise_at + GAP_S - MAX_LEAD_S


async def noise_in_the_gap() -> tuple[Sending, Drive]:
    """A frame to send as the gap after opening ends, and a byte of noise a third of the way
    into that gap: what went out, and what the drive saw."""
    with raw_pty() as (master, path):
        line = open_line(path)  # heard as it opens: a gap from now
        drive = Drive(master)
        try:
            asyncio.get_running_loop().call_later(GAP_S / 3, drive.make_noise)
            sending = await asyncio.wait_for(send_after_gap(line, picking(deque([REQUEST]), [])), 2)
            assert sending is not None
            await eventually(lambda: drive.requests and drive.wrote, what="the request")
        finally:
            drive.close()
            line.close()
    return sending, drive


async def test_bytes_heard_during_the_gap_start_it_again() -> None:
    """Noise a third of the way into the gap: the frame waits a whole gap from the noise, not
    from the sound before it."""
    for _ in range(3):  # a round whose noise came only after the frame (a stalled loop) is void
        sending, drive = await noise_in_the_gap()
        (noise_at,) = drive.wrote
        if sending.started > noise_at:
            break
    else:
        raise AssertionError("the loop stalled past the gap in every round: nothing to judge")
    ((arrived, _),) = drive.requests
    assert arrived - noise_at >= GAP_S
    assert sending.started - noise_at >= GAP_S


async def test_every_frame_after_a_reply_waits_a_gap_from_the_last_byte_even_bytes_after_it() -> (
    None
):
    """The reader callback carries each transaction (its caller held), and keeps the gap: from
    each reply's end, or from bytes that came after the reply, in its read or during the gap."""
    loop = asyncio.get_running_loop()
    drive: Drive

    def answer(count: int) -> bytes:
        reply = build_frame(1, STOPPED_REPLY)
        if count == 2:  # a byte of noise right behind the reply
            return reply + b"\xff"
        if count == 4:  # a byte of noise a third of the way into the gap after it
            loop.call_later(GAP_S / 3, drive.make_noise)
        return reply

    frames = deque([REQUEST] * 6)
    replied: list[tuple[Sending, bytes]] = []
    with raw_pty() as (master, path):
        line = open_line(path)
        drive = Drive(master, answer)
        try:
            ended = await asyncio.wait_for(
                send_after_gap(
                    line,
                    picking(frames, []),
                    lambda: 0.5,
                    lambda sending, pdu, _heard_at: replied.append((sending, pdu)),
                ),
                5.0,
            )
        finally:
            drive.close()
            line.close()
    assert ended is None  # back only once nothing was left to send
    assert [pdu for _, pdu in replied] == [STOPPED_REPLY] * 6  # the noise spoilt none
    assert len(drive.wrote) == 7  # six replies and the noise in the gap
    for arrived, _ in drive.requests[1:]:
        last_sound = max(at for at in drive.wrote if at < arrived)
        assert arrived - last_sound >= GAP_S


async def test_a_caller_held_idle_has_a_request_sent_in_the_call_that_queues_it() -> None:
    frames: deque[bytes] = deque()
    picked_at: list[float] = []
    with raw_pty() as (master, path):
        line = open_line(path)
        loop = asyncio.get_running_loop()
        on_the_wire: list[bytes] = []

        def queue_a_request() -> None:
            frames.append(REQUEST)
            line.queued()
            try:  # in this very call, with no pass of the loop for the caller
                on_the_wire.append(os.read(master, 256))
            except BlockingIOError:
                on_the_wire.append(b"")

        try:
            loop.call_later(3 * GAP_S, queue_a_request)  # the line idle by then
            sending = await asyncio.wait_for(
                send_after_gap(line, picking(frames, picked_at), idle_for=lambda: 1.0), 2.0
            )
        finally:
            line.close()
    assert on_the_wire == [REQUEST]
    assert sending is not None
    assert sending.frame == REQUEST
    assert len(picked_at) == 2  # nothing at the first gap's end; the request when queued


async def test_a_caller_held_idle_gets_nothing_once_its_idle_time_is_over() -> None:
    idle_s = 0.1
    with raw_pty() as (_, path):
        line = open_line(path)
        try:
            began = time.monotonic()
            sending = await asyncio.wait_for(
                send_after_gap(line, picking(deque(), []), idle_for=lambda: idle_s), 2.0
            )
            held_s = time.monotonic() - began
            # Without an idle time: back as the gap ends, with nothing.
            again = time.monotonic()
            nothing = await asyncio.wait_for(send_after_gap(line, picking(deque(), [])), 2.0)
            back_s = time.monotonic() - again
        finally:
            line.close()
    assert sending is None
    assert held_s >= idle_s
    assert held_s < idle_s + 1.0
    assert nothing is None
    assert back_s < idle_s
