"""The line's ledger: what each drive owes, in order, and markers no owed reply can pass for."""

from __future__ import annotations

import logging

import pytest

from gateway.bus.late_replies import LATE_HORIZON_S, MAX_OWED, LateReplies, is_reply_to
from gateway.modbus.crc import crc_ok
from gateway.modbus.rtu import build_frame


def read(address: int, function: int, start: int, count: int) -> bytes:
    return build_frame(address, bytes((function,)) + start.to_bytes(2) + count.to_bytes(2))


def normal_reply(request: bytes) -> bytes:
    """What a device answers a read or an echo with (its words all 1234H)."""
    if request[1] == 0x08:
        return request
    count = int.from_bytes(request[4:6])
    return build_frame(request[0], bytes((request[1], 2 * count)) + b"\x12\x34" * count)


def exception_reply(request: bytes, code: int = 2) -> bytes:
    return build_frame(request[0], bytes((request[1] | 0x80, code)))


def test_each_echo_marker_carries_a_fresh_value_and_is_a_sound_08h_loop_back() -> None:
    late = LateReplies("line1")
    frames = [late.marker(7) for _ in range(0x10000)]
    for frame in frames[:3]:
        assert frame[:4] == bytes.fromhex("07 08 00 00")  # address, 08H, sub-function 0000
        assert len(frame) == 8
        assert crc_ok(frame)
    values = [int.from_bytes(frame[4:6]) for frame in frames]
    # 65,535 echoes in a row without a repeat: never the probe's 0000 either.
    assert len(set(values[:0xFFFF])) == 0xFFFF
    assert 0 not in values
    older, newer = frames[0], frames[1]
    assert is_reply_to(newer, newer)
    assert not is_reply_to(newer, older)  # same function and length: still never taken for it
    assert is_reply_to(newer, build_frame(7, bytes.fromhex("8801")))  # a device without 08H


def test_a_late_reply_takes_off_its_request_and_every_one_owed_before_it() -> None:
    late = LateReplies("line1")
    first, second, third = read(3, 3, 0x2100, 2), read(3, 3, 0x3000, 12), read(3, 3, 0x5000, 1)
    for at, frame in enumerate((first, second, third)):
        late.unanswered(3, frame, 100.0 + at)
    # The answer to the second: the first was answered or never will be (in order).
    answered = late.heard(normal_reply(second))
    assert answered is not None
    assert answered.sent_at == 101.0
    assert late.owed_frames(3) == (third,)
    assert late.owes(3)
    answered = late.heard(normal_reply(third))
    assert answered is not None
    assert answered.sent_at == 102.0
    assert not late.owes(3)  # its last owed reply came: in step, no marker needed


def test_of_two_owed_requests_alike_a_reply_takes_off_only_the_first() -> None:
    """Conservative: it may be the first's, so the second stays owed."""
    late = LateReplies("line1")
    state, again = read(1, 3, 0x2100, 2), read(1, 3, 0x2100, 2)
    late.unanswered(1, state, 1.0)
    late.unanswered(1, again, 2.0)
    late.heard(normal_reply(state))
    assert late.owed_frames(1) == (again,)


def test_a_frame_that_answers_nothing_owed_leaves_its_drive_unsure_until_a_marker() -> None:
    late = LateReplies("line1")
    assert late.heard(normal_reply(read(2, 3, 0x3000, 2))) is None  # it owed nothing
    assert late.owes(2)
    marker = late.marker(2)
    late.caught_up(2, marker)
    assert not late.owes(2)


def test_markers_are_reads_no_owed_reply_looks_like_each_in_turn_when_one_is_missed() -> None:
    late = LateReplies("line1")
    owed = [read(1, 3, 0x0000, 1), read(1, 3, 0x0010, 4), read(1, 4, 0x0000, 2)]
    for frame in owed:
        late.unanswered(1, frame, 1e12)  # recent: each narrows the choice
    markers = []
    for _ in range(6):
        marker = late.marker(1)
        markers.append(marker)
        assert marker[1] in (0x03, 0x04), "a device without 08H is never sent an echo"
        for reply in (normal_reply(marker), exception_reply(marker)):
            if reply[1] & 0x80 and any(m[1] == marker[1] for m in owed):
                continue  # an exception of an owed function: the reader sets it aside
            assert is_reply_to(marker, reply)
            assert not any(is_reply_to(request, reply) for request in owed)
        late.marker_missed(1, marker)
    assert len(set(markers)) > 1, "a missed read is followed by another"


def test_a_drive_that_answered_an_echo_gets_one_when_a_read_goes_unanswered(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.WARNING)
    late = LateReplies("line1")
    late.answered[1] = read(1, 3, 0x2100, 2)
    late.unanswered(1, read(1, 3, 0x2100, 2), 1e12)
    first = late.marker(1)
    assert first[1] == 0x04
    late.marker_missed(1, first)
    assert late.marker(1)[1] != 0x08  # never answered an echo: reads only
    echo = build_frame(1, bytes.fromhex("0800000007"))
    late.unanswered(1, echo, 1e12)
    late.heard(echo)  # it answers echoes
    late.unanswered(1, read(1, 3, 0x2100, 2), 1e12)
    assert late.marker(1)[1] == 0x08  # a read went unanswered last: the echo, which it answers
    # A read answered after an echo sent before it went unanswered: no 08H, learnt, said.
    late.unanswered(1, echo, 1e12)
    late.unanswered(1, read(1, 4, 0x2100, 1), 1e12)
    late.heard(exception_reply(read(1, 4, 0x2100, 1), 1))
    assert 1 in late.no_echo
    assert "not the diagnostic echo" in caplog.text


def test_a_written_register_is_read_back_as_the_marker_of_a_device_without_08h() -> None:
    late = LateReplies("line1")
    late.no_echo.add(5)
    write = build_frame(5, bytes.fromhex("06 0002 0064"))
    late.unanswered(5, write, 1e12)
    marker = late.marker(5)
    assert marker[1] in (0x03, 0x04)
    assert marker[2:4] == b"\x00\x02"


def test_an_owed_request_older_than_the_horizon_no_longer_narrows_the_marker() -> None:
    late = LateReplies("line1")
    late.no_echo.add(4)
    only = read(4, 3, 0x0000, 1)
    late.answered[4] = only
    late.unanswered(4, only, 0.0)  # long ago
    late.unanswered(4, read(4, 4, 0x0000, 1), 0.0)
    # Both owed long ago: the read the device answered, as 04H, may be the marker although an
    # owed 04H read looks the same; recent, it could not be.
    assert late.marker(4) == read(4, 4, 0, 1)
    late.owing.clear()
    late.unanswered(4, read(4, 4, 0x0000, 1), 1e12)
    assert late.marker(4) != read(4, 4, 0, 1)
    assert LATE_HORIZON_S >= 5  # well beyond any drive's delay (P14.03 is at most 200 ms)


@pytest.mark.parametrize("count", [1, 2, 12])
def test_every_read_marker_of_a_read_is_told_from_its_reply(count: int) -> None:
    late = LateReplies("line1")
    late.no_echo.add(9)
    for function in (3, 4):
        owed = read(9, function, 0x1000, count)
        late.owing.clear()
        late.unanswered(9, owed, 1e12)
        for _ in range(4):
            marker = late.marker(9)
            assert not is_reply_to(owed, normal_reply(marker))
            late.marker_missed(9, marker)


def test_a_retry_of_the_same_transaction_needs_no_marker_the_next_transaction_does() -> None:
    late = LateReplies("line1")
    request = read(1, 3, 0x2100, 2)
    first, second = object(), object()
    assert not late.needs_marker(1, request, first)  # owes nothing
    late.unanswered(1, request, 1e12, first)
    # Whichever send a reply answers, it answers what this transaction's client asked.
    assert not late.needs_marker(1, request, first)
    assert late.needs_marker(1, read(1, 3, 0x3000, 2), first)  # another question
    assert late.needs_marker(1, request, second)  # never a reply one request behind
    late.broadcast()  # values from before a broadcast write: a marker even for the retry
    assert late.needs_marker(1, request, first)


def test_a_dead_drive_s_owed_requests_are_bounded_and_it_stays_unsure() -> None:
    late = LateReplies("line1")
    probe = read(7, 3, 0x2100, 1)
    for second in range(2000):  # a probe a second, never answered
        late.unanswered(7, probe, 1000.0 + second)
    assert len(late.owed_frames(7)) <= LATE_HORIZON_S + 1
    for burst in range(500):  # a burst of timeouts within the horizon
        late.unanswered(7, probe, 5000.0 + burst / 1000)
    assert len(late.owed_frames(7)) == MAX_OWED
    assert late.needs_marker(7, probe, object())
    assert 7 in late.unsure


def test_only_an_illegal_function_exception_marks_a_read_function_refused() -> None:
    late = LateReplies("line1")
    late.heard(exception_reply(read(2, 3, 0x0100, 9), 2))  # an illegal address: 03H still served
    assert 3 not in late.refused.get(2, set())
    late.heard(exception_reply(read(2, 4, 0x0100, 1), 1))  # 04H not served at all
    assert late.refused[2] == {4}
