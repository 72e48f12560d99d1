"""Property-based tests of the frame code: random and mutated bytes never crash a parser, never
pass for a valid frame they aren't, and never put the RTU line out of step.

The pure parsers (MBAP header, RTU reply length, reply check) take any bytes. The RTU reply
assembly runs on a real pty: a scripted drive answers each request with hostile bytes, then
answers the next request correctly, which must come through exactly (a desynchronised master
would take leftovers of the first answer for the second).
"""

from __future__ import annotations

import asyncio
import itertools
import os
import select
import struct
import threading
import time
import tty
from collections.abc import Iterator
from dataclasses import dataclass, field

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gateway.bus.line import Exchange, LineSettings, SerialLine
from gateway.errors import BadReply, MalformedFrame, ReplyTimeout
from gateway.modbus.crc import crc_bytes
from gateway.modbus.functions import NEED_MORE, UNKNOWN_LENGTH, rtu_reply_length
from gateway.modbus.mbap import (
    HEADER_LENGTH,
    MAX_LENGTH,
    MIN_LENGTH,
    build_adu,
    frame_header,
    parse_header,
)
from gateway.modbus.reply_search import Found, search_reply
from gateway.modbus.rtu import (
    build_frame,
    check_reply,
    plain_read,
    plain_read_reply,
    request_frame,
)
from gateway.modbus.timing import CharacterFormat

PURE = settings(max_examples=500, deadline=None, database=None)


# -- MBAP ----------------------------------------------------------------------------------------


@PURE
@given(st.binary(min_size=HEADER_LENGTH, max_size=HEADER_LENGTH))
def test_any_seven_bytes_are_a_valid_header_or_malformed(data: bytes) -> None:
    try:
        header = parse_header(data)
    except MalformedFrame:
        _, protocol, length, _ = struct.unpack(">HHHB", data)
        assert protocol != 0 or not MIN_LENGTH <= length <= MAX_LENGTH
        return
    assert header.protocol_id == 0
    assert 1 <= header.pdu_length <= MAX_LENGTH - 1
    # What was parsed is what a reply to it carries back.
    pdu = bytes(header.pdu_length)
    assert build_adu(header.transaction_id, header.unit_id, pdu)[:HEADER_LENGTH] == data


@PURE
@given(st.binary(max_size=12).filter(lambda b: len(b) != HEADER_LENGTH))
def test_a_header_of_the_wrong_size_is_malformed(data: bytes) -> None:
    with pytest.raises(MalformedFrame):
        parse_header(data)


# -- RTU, pure -------------------------------------------------------------------------------------

ADDRESS = 1
READ_REQUEST = build_frame(ADDRESS, bytes.fromhex("03 21 00 00 02"))


@PURE
@given(st.binary(max_size=300), st.integers(min_value=4, max_value=256))
def test_reply_length_once_reached_never_changes(data: bytes, request_length: int) -> None:
    # A length beyond the bytes seen may be a step (18H, 2BH/0EH read their header field by
    # field); once the bytes reach it, it is the reply's, and more bytes don't change it.
    decided = None
    for end in range(len(data) + 1):
        length = rtu_reply_length(data[:end], request_length)
        if decided is None:
            if length not in (NEED_MORE, UNKNOWN_LENGTH):
                assert 4 <= length <= 260
                if end >= length:
                    decided = length
        else:
            assert length == decided, "more bytes changed an already decided length"


@PURE
@given(st.binary(max_size=300))
def test_random_bytes_never_pass_for_a_reply(reply: bytes) -> None:
    try:
        pdu = check_reply(READ_REQUEST, reply)
    except BadReply as exc:
        kind = exc.kind
        assert kind in {"crc", "truncated", "address", "function", "mismatch"}
        return
    # Accepted only when it is byte for byte a frame from the right address, right function.
    assert build_frame(ADDRESS, pdu) == reply
    assert pdu[0] in (0x03, 0x83)


@st.composite
def mutated_replies(draw: st.DrawFn) -> bytes:
    """A good 03H reply, then spoilt the ways a line spoils it (or left alone)."""
    words = draw(st.lists(st.integers(0, 0xFFFF), min_size=1, max_size=16))
    good = build_frame(ADDRESS, struct.pack(f">BB{len(words)}H", 3, 2 * len(words), *words))
    kind = draw(st.sampled_from(["none", "flip", "truncate", "extend", "address", "exception"]))
    if kind == "flip":
        position = draw(st.integers(0, len(good) - 1))
        bit = 1 << draw(st.integers(0, 7))
        return good[:position] + bytes((good[position] ^ bit,)) + good[position + 1 :]
    if kind == "truncate":
        return good[: draw(st.integers(0, len(good) - 1))]
    if kind == "extend":
        return good + draw(st.binary(min_size=1, max_size=8))
    if kind == "address":
        body = bytes((draw(st.integers(0, 255).filter(lambda a: a != ADDRESS)),)) + good[1:-2]
        return body + crc_bytes(body)
    if kind == "exception":
        return build_frame(ADDRESS, bytes((0x83, draw(st.integers(0, 255)))))
    return good


@PURE
@given(mutated_replies())
def test_a_mutated_reply_is_refused_unless_it_is_still_exactly_a_reply(reply: bytes) -> None:
    # The parser sees what the line assembly hands it: the frame cut at its expected length.
    length = rtu_reply_length(reply, len(READ_REQUEST))
    framed = reply[:length] if length > 0 else reply
    try:
        pdu = check_reply(READ_REQUEST, framed)
    except BadReply:
        return
    assert build_frame(ADDRESS, pdu) == framed


# -- RTU reply assembly on a real pty ------------------------------------------------------------


@dataclass
class ScriptedDrive:
    """The far end of a pty: answers each request it reads with the next scripted bytes."""

    fd: int
    script: list[list[bytes]] = field(default_factory=list)
    requests: list[bytes] = field(default_factory=list)
    _stop: threading.Event = field(default_factory=threading.Event)

    def serve(self) -> None:
        while not self._stop.is_set():
            ready, _, _ = select.select([self.fd], [], [], 0.05)
            if not ready:
                continue
            self.requests.append(os.read(self.fd, 512))
            for chunk in self.script.pop(0) if self.script else []:
                os.write(self.fd, chunk)  # separate writes: they may arrive in separate reads

    def stop(self) -> None:
        self._stop.set()


@dataclass
class LineOnLoop:
    """The event-loop line, driven one exchange at a time as the field tools drive it."""

    line: SerialLine
    loop: asyncio.AbstractEventLoop

    def transact(self, frame: bytes, timeout_s: float) -> Exchange:
        return self.loop.run_until_complete(
            self.line.transact(frame, expect_reply=True, timeout_s=timeout_s)
        )


@pytest.fixture(scope="module")
def pty_line() -> Iterator[tuple[LineOnLoop, ScriptedDrive]]:
    master, slave = os.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    drive = ScriptedDrive(master)
    thread = threading.Thread(target=drive.serve, name="scripted-drive", daemon=True)
    thread.start()
    line = SerialLine(
        LineSettings(
            port=os.ttyname(slave),
            # Parity N: a pty refuses re-configuration once a parity is set.
            char_format=CharacterFormat(115200, "N", 1, 8),
            gap_s=0.00175,
            char_timeout_s=0.005,
            drain_s=0.01,
            turnaround_s=0.0,
        )
    )
    loop = asyncio.new_event_loop()

    async def open_line() -> None:
        line.open()

    loop.run_until_complete(open_line())
    try:
        yield LineOnLoop(line, loop), drive
    finally:
        line.close()
        loop.close()
        drive.stop()
        thread.join(1)
        os.close(master)
        os.close(slave)


hostile_replies = st.one_of(
    st.binary(max_size=300),
    mutated_replies(),
    st.just(b""),
)


@settings(
    max_examples=120,
    deadline=None,
    database=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(
    reply=hostile_replies,
    splits=st.lists(st.integers(1, 300), max_size=3),
    words=st.lists(st.integers(0, 0xFFFF), min_size=2, max_size=2),  # what READ_REQUEST asks
)
def test_hostile_bytes_on_the_line_never_pass_and_never_desynchronise(
    pty_line: tuple[LineOnLoop, ScriptedDrive], reply: bytes, splits: list[int], words: list[int]
) -> None:
    line, drive = pty_line
    cuts = sorted({0, *(s for s in splits if s < len(reply)), len(reply)})
    chunks = [reply[a:b] for a, b in itertools.pairwise(cuts)]
    good_pdu = struct.pack(f">BB{len(words)}H", 3, 2 * len(words), *words)
    drive.requests.clear()
    drive.script = [chunks, [build_frame(ADDRESS, good_pdu)]]
    try:
        exchange = line.transact(READ_REQUEST, timeout_s=0.03)
    except (BadReply, ReplyTimeout):
        pass
    else:
        assert exchange.reply_pdu is not None
        frame = build_frame(ADDRESS, exchange.reply_pdu)
        assert reply.startswith(frame), "accepted something that is not the start of the reply"
    # The next exchange gets exactly its own reply: nothing of the hostile one is left over.
    exchange = line.transact(READ_REQUEST, timeout_s=0.2)
    assert exchange.reply_pdu == good_pdu
    assert not drive.script


def test_bytes_arriving_between_two_exchanges_are_never_taken_for_the_next_reply(
    pty_line: tuple[LineOnLoop, ScriptedDrive],
) -> None:
    """A late reply from another drive lands while nobody reads the line (a field tool between
    two requests): the next exchange still gets exactly its own reply."""
    line, drive = pty_line
    good_pdu = bytes.fromhex("03 04 00 01 00 02")
    drive.requests.clear()
    drive.script = [[build_frame(ADDRESS, good_pdu)]]
    assert line.transact(READ_REQUEST, timeout_s=0.2).reply_pdu == good_pdu
    os.write(drive.fd, build_frame(ADDRESS + 1, bytes.fromhex("03 04 00 09 00 09")))
    time.sleep(0.02)  # the line is quiet again for far longer than t3.5
    drive.script = [[build_frame(ADDRESS, good_pdu)]]
    assert line.transact(READ_REQUEST, timeout_s=0.2).reply_pdu == good_pdu
    assert not drive.script


# -- the hot path's shortcuts agree with the general parsers ---------------------------------


@PURE
@given(st.binary(min_size=HEADER_LENGTH, max_size=HEADER_LENGTH + 4))
def test_the_servers_header_read_agrees_with_parse_header(data: bytes) -> None:
    try:
        header = parse_header(data[:HEADER_LENGTH])
    except MalformedFrame as expected:
        with pytest.raises(MalformedFrame, match=str(expected)):
            frame_header(bytearray(data))
        return
    assert frame_header(bytearray(data)) == (
        header.transaction_id,
        header.unit_id,
        header.pdu_length,
    )


def _general_verdict(received: bytes, request: bytes) -> bytes | None:
    """What the reply search and the reply check make of `received`, whole: the PDU, or None."""
    search = search_reply(received, request)
    if search.found is not Found.COMPLETE or search.start or search.end != len(received):
        return None
    try:
        return check_reply(request, received[search.start : search.end], crc_checked=True)
    except BadReply:
        return None


_plain_reads = st.builds(
    lambda address, function, start, count: build_frame(
        address, struct.pack(">BHH", function, start, count)
    ),
    st.integers(1, 247),
    st.sampled_from([3, 4]),
    st.integers(0, 0xFFFF),
    st.integers(1, 125),
)


@PURE
@given(_plain_reads, st.data())
def test_a_plain_reads_reply_is_taken_only_where_the_search_would_take_it(
    request: bytes, data: st.DataObject
) -> None:
    expected = plain_read(request)
    assert expected is not None
    length = expected.length
    assert length == 5 + 2 * struct.unpack(">H", request[4:6])[0]
    good = build_frame(request[0], bytes((request[1], length - 5)) + bytes(length - 5))
    received = data.draw(
        st.one_of(
            st.just(good),
            st.binary(min_size=length, max_size=length),  # noise of the right length
            st.builds(  # the good reply with one byte changed
                lambda i, b: good[:i] + bytes((b,)) + good[i + 1 :],
                st.integers(0, length - 1),
                st.integers(0, 255),
            ),
            st.just(request[:length]),  # the adapter's echo, so far
            st.just(good[:-1]),  # still coming
        )
    )
    fast = plain_read_reply(received, expected)
    if fast is not None:
        assert fast == _general_verdict(received, request) == received[1:-2]
    if received == good:
        assert fast == good[1:-2]


@pytest.mark.parametrize(
    "request_hex",
    ["01 06 20 00 00 01", "01 10 20 00 00 01 02 00 01", "01 03 21 00 00 00", "01 03 21 00 00 7E"],
)
def test_requests_other_than_plain_reads_have_no_shortcut(request_hex: str) -> None:
    assert plain_read(build_frame(1, bytes.fromhex(request_hex)[1:])) is None


@PURE
@given(st.integers(0, 247), st.binary(min_size=1, max_size=20))
def test_a_remembered_request_frame_is_the_frame(address: int, pdu: bytes) -> None:
    assert request_frame(address, pdu) == build_frame(address, pdu) == request_frame(address, pdu)
