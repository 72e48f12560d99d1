"""What a redundant gateway takes for another master's request among the bytes it hears
(`gateway.redundancy.frames`): requests apart from replies, whatever pieces they come in."""

from __future__ import annotations

import itertools

from gateway.modbus.crc import crc_ok
from gateway.modbus.rtu import build_frame
from gateway.redundancy.frames import Frame, FrameCutter, Kind

READ = build_frame(1, bytes.fromhex("0330000002"))
READ_REPLY = build_frame(1, bytes.fromhex("030400010002"))
WRITE = build_frame(1, bytes.fromhex("0620010100"))
WRITE_MANY = build_frame(1, bytes.fromhex("10200000020400010002"))
WRITE_MANY_REPLY = build_frame(1, bytes.fromhex("1020000002"))
EXCEPTION = build_frame(1, bytes.fromhex("8302"))


def cut(*pieces: bytes) -> list[Frame]:
    cutter = FrameCutter()
    frames = [frame for piece in pieces for frame in cutter.feed(piece)]
    return frames + cutter.silence()


def test_a_line_s_traffic_is_told_apart() -> None:
    heard = cut(READ + READ_REPLY + WRITE + WRITE + WRITE_MANY + WRITE_MANY_REPLY + EXCEPTION)
    assert [f.kind for f in heard] == [
        Kind.REQUEST,
        Kind.REPLY,
        Kind.ECHO_FORM,
        Kind.ECHO_FORM,
        Kind.REQUEST,
        Kind.REPLY,
        Kind.REPLY,
    ]
    assert heard[0].data == READ
    assert heard[4].data == WRITE_MANY


def test_pieces_anywhere_make_the_same_frames() -> None:
    stream = READ + READ_REPLY + WRITE_MANY + WRITE_MANY_REPLY
    whole = cut(stream)
    for first, second in itertools.combinations(range(1, len(stream)), 2):
        assert cut(stream[:first], stream[first:second], stream[second:]) == whole


def test_noise_before_a_request_is_skipped() -> None:
    assert cut(b"\xff\x00" + READ) == [Frame(Kind.REQUEST, READ)]


def reply_with_a_good_crc_at_8_bytes() -> bytes:
    """A 03H reply of two words whose first 8 bytes end in their own good CRC (one reply in
    65,536 does): found by trying the words' values."""
    for value in range(0x10000):
        words = bytes.fromhex("010304") + value.to_bytes(2, "big")
        for third in range(0x100):
            start = words + bytes([third])
            crc = build_frame(start[0], start[1:])[-2:]  # the CRC of the first 6 bytes
            reply = build_frame(1, start[1:] + crc[:1])
            if reply[7] == crc[1]:
                return reply
    raise AssertionError("none found")


def test_a_reply_whose_first_bytes_carry_a_good_crc_is_a_reply() -> None:
    reply = reply_with_a_good_crc_at_8_bytes()
    assert len(reply) == 9
    assert crc_ok(reply[:8])  # read as a request, 8 bytes would pass
    assert cut(reply[:8], reply[8:]) == [Frame(Kind.REPLY, reply)]
    assert cut(reply) == [Frame(Kind.REPLY, reply)]
