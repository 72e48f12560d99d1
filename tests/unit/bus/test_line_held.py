"""Back-to-back transactions carried by the line's own callbacks: while requests keep coming,
the port's reader callback takes each whole reply, keeps the gap and sends the next frame, and
the caller (the bus's coroutine) is not woken in between; a reply that is not plainly whole and
valid goes back to the caller's own reading. Over a real pty with simulated drives."""

from __future__ import annotations

import asyncio
import itertools
import os
import time
import tty
from collections import deque
from collections.abc import Callable

import pytest

from gateway.bus.line import Sending, SerialLine
from gateway.config import BusConfig
from gateway.errors import BadReply, PortError, ReplyTimeout
from gateway.instruments.simulator import SimulatedLine
from gateway.modbus.rtu import build_frame
from gateway.modbus.timing import FAST_T35_S
from gateway.settings import bus_settings
from tests.support import read_pdu, write_pdu
from tests.unit.bus.line_users import send_after_gap

STATE_WORD_1 = 0x2100
FREQUENCY_SETPOINT = 0x2001
STOPPED_REPLY = bytes.fromhex("03 02 00 03")
SILENT = 9
HELD_FROM_START_S = 0.02
"""Well within the 50 ms the tests wait for a request to be out."""

pytestmark = pytest.mark.line(addresses=[1, 2])


def open_line(path: str, baudrate: int = 115200) -> SerialLine:
    config = BusConfig.model_validate({"name": "line1", "port": path, "baudrate": baudrate})
    line = SerialLine(bus_settings(config).line)
    line.open()
    # As if the line was heard a moment from now: the first frame waits for its gap in the
    # timer's callback and its caller is held, as for every frame after a reply. Else, on a
    # loaded machine, the 1.75 ms gap after opening may be over before the caller's coroutine
    # first runs, and the frame goes at once with nobody held (what these tests look at).
    line.receiver.quiet_since = time.monotonic() + HELD_FROM_START_S
    return line


def picking(frames: deque[bytes]) -> Callable[[], bytes | None]:
    """`Dispatch.pick` for these tests: the next frame, until there is none."""
    return lambda: frames.popleft() if frames else None


async def test_the_caller_stays_held_while_the_reader_callback_carries_each_transaction(
    line: SimulatedLine,
) -> None:
    frames = deque(build_frame(1 + n % 2, read_pdu(STATE_WORD_1)) for n in range(10))
    replied: list[tuple[Sending, bytes, float]] = []
    serial = open_line(line.path)
    try:
        # Every frame but the first is picked in a callback, after the reply before it.
        ended = await asyncio.wait_for(
            send_after_gap(
                serial,
                picking(frames),
                lambda: 0.5,
                lambda sending, pdu, heard_at: replied.append((sending, pdu, heard_at)),
            ),
            5.0,
        )
    finally:
        serial.close()
    assert ended is None  # back only once nothing was left to send
    assert [pdu for _, pdu, _ in replied] == [STOPPED_REPLY] * 10
    assert [sending.frame[0] for sending, _, _ in replied] == [1, 2] * 5  # in the order picked
    assert line.stats["requests"] == 10
    # Each frame after the first waited a whole t3.5 after the reply before it.
    assert all(sending.gap_s >= FAST_T35_S for sending, _, _ in replied[1:])
    # Each reply was heard after its frame went out, and before the next frame's gap began.
    assert all(sending.started < heard_at for sending, _, heard_at in replied)
    assert all(
        heard_at + FAST_T35_S <= after.started
        for (_, _, heard_at), (after, _, _) in itertools.pairwise(replied)
    )
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
            send_after_gap(
                serial,
                picking(frames),
                lambda: 0.05,
                lambda _sending, pdu, _heard_at: replied.append(pdu),
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


@pytest.mark.line(addresses=[1])
async def test_a_held_caller_whose_drive_is_silent_wakes_at_its_response_timeout_not_before(
    line: SimulatedLine,
) -> None:
    """The response timeout of a held caller: from the request's end on the wire, never early,
    and not long after either (a timer that moves only when it fires must still fire on time)."""
    within_s = 0.15
    serial = open_line(line.path)
    try:
        waiting = await asyncio.wait_for(
            send_after_gap(
                serial,
                picking(deque([build_frame(SILENT, read_pdu(STATE_WORD_1))])),
                lambda: within_s,
                lambda _sending, _pdu, _heard_at: None,
            ),
            5.0,
        )
        woken = time.monotonic()
        assert waiting is not None
        sent = waiting.started + serial.settings.char_format.wire_time_s(len(waiting.frame))
        assert woken >= sent + within_s
        assert woken < sent + within_s + 0.1
    finally:
        serial.close()


@pytest.mark.line(addresses=[1])
async def test_a_port_that_fails_while_the_caller_is_held_is_reported_at_once(
    line: SimulatedLine,
) -> None:
    """An adapter pulled while a request waits for its reply: the caller hears of it when it
    happens, not once the response timeout has passed."""
    serial = open_line(line.path)
    try:
        held = asyncio.ensure_future(
            send_after_gap(
                serial,
                picking(deque([build_frame(SILENT, read_pdu(STATE_WORD_1))])),
                lambda: 10.0,
                lambda _sending, _pdu, _heard_at: None,
            )
        )
        await asyncio.sleep(0.05)  # the request is out, its caller held until a reply
        assert not held.done()
        unplugged = time.monotonic()
        line.unplug()
        waiting = await asyncio.wait_for(held, 5.0)
        assert waiting is not None
        with pytest.raises(PortError):
            await asyncio.wait_for(serial.finish(waiting, expect_reply=True, timeout_s=10.0), 5.0)
        assert time.monotonic() - unplugged < 2.0
    finally:
        serial.close()


async def test_a_frame_the_ports_buffer_refuses_at_the_gaps_end_goes_out_through_its_caller(
    line: SimulatedLine, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A frame the port's buffer refuses at the gap's end (`TtyPort.write_now` takes nothing)
    is not lost: the attempt goes back to its caller with nothing written, whose own `finish`
    writes it whole and reads its reply; the frames after it are held as ever."""
    frames = deque(build_frame(1 + n % 2, read_pdu(STATE_WORD_1)) for n in range(4))
    sent = set(frames)
    refused: list[bytes] = []
    write = os.write

    def write_once_refused(fd: int, data: bytes) -> int:
        if data in sent and data not in refused:
            refused.append(data)
            raise BlockingIOError
        return write(fd, data)

    monkeypatch.setattr(os, "write", write_once_refused)
    replied: list[tuple[Sending, bytes]] = []
    finished: list[bytes | None] = []
    serial = open_line(line.path)
    try:
        while True:
            ended = await asyncio.wait_for(
                send_after_gap(
                    serial,
                    picking(frames),
                    lambda: 0.5,
                    lambda sending, pdu, _heard_at: replied.append((sending, pdu)),
                ),
                5.0,
            )
            if ended is None:
                break
            assert ended.written == 0  # refused at the gap's end: its caller writes it
            exchange = await serial.finish(ended, expect_reply=True, timeout_s=0.5)
            finished.append(exchange.reply_pdu)
    finally:
        serial.close()
    assert len(refused) == 2  # the two distinct frames, each refused once at the gap's end
    assert finished == [STOPPED_REPLY] * 2
    assert [pdu for _, pdu in replied] == [STOPPED_REPLY] * 2
    assert line.stats["requests"] == 4
    assert line.stats["gap_violations"] == 0


async def test_a_failure_in_the_callers_hook_reaches_the_caller(line: SimulatedLine) -> None:
    frames = deque(build_frame(1, read_pdu(STATE_WORD_1)) for _ in range(3))

    def replied(_sending: Sending, _pdu: bytes, _heard_at: float) -> None:
        raise RuntimeError("a bug in the bus")

    serial = open_line(line.path)
    try:
        with pytest.raises(RuntimeError, match="a bug in the bus"):
            await asyncio.wait_for(
                send_after_gap(serial, picking(frames), lambda: 0.5, replied),
                5.0,
            )
    finally:
        serial.close()
    assert len(frames) == 2  # nothing more was sent after the failure


async def test_an_echo_seen_while_held_is_still_known_for_one_when_the_reply_stops_short() -> None:
    """An adapter that echoes though `echo: false` says it doesn't, and a 06H reply cut short:
    the echo (a copy of the request, which a 06H reply is too) came back sooner than the request
    could cross the wire, so it is the echo, and the attempt fails as truncated. It must never
    pass for the drive's acknowledgement, whichever reading (the callback's or the caller's)
    ends the attempt."""
    master, slave = os.openpty()
    tty.setraw(slave)
    loop = asyncio.get_running_loop()
    request = build_frame(1, write_pdu(FREQUENCY_SETPOINT, 2500))
    heard = bytearray()

    def adapter_and_drive() -> None:
        heard.extend(os.read(master, 256))
        if len(heard) == len(request):
            os.write(master, bytes(heard))  # the adapter's echo, at once
            # The drive's reply starts after its response delay, and stops after 5 bytes.
            loop.call_later(0.03, os.write, master, request[:5])

    loop.add_reader(master, adapter_and_drive)
    serial = open_line(os.ttyname(slave), baudrate=9600)
    # Judged as a wire, not a pty: the echo is told from the reply by its timing.
    serial.receiver.virtual = False
    try:
        frames = deque([request])
        waiting = await asyncio.wait_for(
            send_after_gap(serial, picking(frames), lambda: 0.1, lambda *_: None),
            5.0,
        )
        assert waiting is not None  # not carried by the callback: the reply never completed
        with pytest.raises(BadReply) as failed:
            await serial.finish(waiting, expect_reply=True, timeout_s=0.1)
        assert failed.value.kind == "truncated"
    finally:
        serial.close()
        loop.remove_reader(master)
        os.close(master)
        os.close(slave)
