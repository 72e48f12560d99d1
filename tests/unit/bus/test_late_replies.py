"""The echo that catches up with a drive's late replies carries a value no echo in flight has."""

from __future__ import annotations

import pytest

from gateway.bus.late_replies import LateReplies
from gateway.modbus.crc import crc_ok


def test_each_echo_carries_a_fresh_value_and_is_a_sound_08h_loop_back() -> None:
    late = LateReplies("line1")
    frames = [late.echo_frame(7) for _ in range(0x10000)]
    for frame in frames[:3]:
        assert frame[:4] == bytes.fromhex("07 08 00 00")  # address, 08H, sub-function 0000
        assert len(frame) == 8
        assert crc_ok(frame)
    values = [int.from_bytes(frame[4:6]) for frame in frames]
    # 65,535 echoes in a row without a repeat: never the probe's 0000 either.
    assert len(set(values[:0xFFFF])) == 0xFFFF
    assert 0 not in values


def test_a_drive_owes_from_its_first_timeout_until_its_echo_is_back() -> None:
    late = LateReplies("line1")
    late.timed_out(3, 10.0)
    late.timed_out(3, 11.0)  # still the first request it left unanswered
    assert late.owing == {3: 10.0}
    late.caught_up(3)
    assert late.owing == {}


def test_only_the_echo_of_this_very_value_ends_a_catch_up() -> None:
    """An older echo (another value) has the same function and length: by those alone it
    would pass, and the bus would think itself caught up with a reply still in flight."""
    from gateway.bus.receiver import echo_of as _echo_of
    from gateway.errors import BadReply
    from gateway.modbus.rtu import build_frame

    late = LateReplies("line1")
    older, newer = late.echo_frame(1), late.echo_frame(1)
    assert _echo_of(newer, newer) == newer[1:-2]
    with pytest.raises(BadReply) as refused:  # never taken for this one
        _echo_of(newer, older)
    assert refused.value.kind == "mismatch"
    no_08h = build_frame(1, bytes.fromhex("8801"))  # a device without 08H: in order too
    assert _echo_of(newer, no_08h) == bytes.fromhex("8801")
