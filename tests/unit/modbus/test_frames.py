"""Frame code, bytes in and bytes out: CRC, reply lengths, MBAP and RTU checks."""

from __future__ import annotations

import pytest
from pymodbus.framer import FramerRTU

from gateway.errors import BadReply, MalformedFrame
from gateway.modbus.crc import crc16, crc_bytes, crc_ok
from gateway.modbus.functions import NEED_MORE, UNKNOWN_LENGTH, exception_pdu, rtu_reply_length
from gateway.modbus.mbap import build_adu, parse_header
from gateway.modbus.rtu import build_frame, check_reply
from tests.support.protocol_frames import PROTOCOL_FRAMES


@pytest.mark.parametrize("frame_hex", PROTOCOL_FRAMES)
def test_crc_of_every_protocol_frame(frame_hex: str) -> None:
    frame = bytes.fromhex(frame_hex)
    assert crc_bytes(frame[:-2]) == frame[-2:]
    assert crc_ok(frame)
    assert build_frame(frame[0], frame[1:-2]) == frame


@pytest.mark.parametrize("frame_hex", PROTOCOL_FRAMES)
def test_crc_agrees_with_pymodbus(frame_hex: str) -> None:
    body = bytes.fromhex(frame_hex)[:-2]
    # pymodbus returns the CRC with its bytes swapped for big-endian packing.
    theirs = FramerRTU.compute_CRC(body)
    assert crc16(body) == int.from_bytes(theirs.to_bytes(2, "big"), "little")


def test_manuals_misprinted_crc_is_rejected() -> None:
    # The manuals print C5 6E for the 10H frames; PROTOCOL.md says that is wrong.
    assert not crc_ok(bytes.fromhex("02 10 00 04 00 02 04 13 88 00 32 C5 6E"))


@pytest.mark.parametrize(
    ("request_hex", "reply_hex"),
    [
        ("01 03 00 04 00 02 85 CA", "01 03 04 13 88 00 00 7E 9D"),
        ("01 08 00 00 12 AB AD 14", "01 08 00 00 12 AB AD 14"),
        ("02 06 00 04 13 88 C5 6E", "02 06 00 04 13 88 C5 6E"),
        ("02 10 00 04 00 02 04 13 88 00 32 F8 63", "02 10 00 04 00 02 00 3A"),
        ("01 06 00 01 00 03 98 0B", "01 86 04 43 A3"),
        ("03 03 07 1B 00 06 B5 59", "03 03 0C 00 23 00 23 00 23 00 23 00 23 00 23 5F D2"),
    ],
)
def test_reply_length_is_known_from_its_first_bytes(request_hex: str, reply_hex: str) -> None:
    request, reply = bytes.fromhex(request_hex), bytes.fromhex(reply_hex)
    assert rtu_reply_length(reply[:1], len(request)) == NEED_MORE
    assert rtu_reply_length(reply[:3], len(request)) == len(reply)
    assert check_reply(request, reply) == reply[1:-2]


def test_exception_reply_length_is_known_after_two_bytes() -> None:
    assert rtu_reply_length(bytes.fromhex("01 86"), 8) == 5
    assert rtu_reply_length(bytes.fromhex("01 83"), 8) == 5


def test_unknown_function_has_no_length() -> None:
    assert rtu_reply_length(bytes.fromhex("01 41 00"), 8) == UNKNOWN_LENGTH


@pytest.mark.parametrize(
    ("reply_hex", "kind"),
    [
        ("01 03 04 13 88 00 00 7E 9E", "crc"),  # last CRC byte off by one
        ("02 03 04 13 88 00 00 7E 9D", "crc"),  # address changed, CRC no longer fits
        ("01 03", "truncated"),
        ("01 04 02 00 03 F9 31", "function"),  # a valid 04H frame answering a 03H request
    ],
)
def test_bad_replies_are_refused_with_their_reason(reply_hex: str, kind: str) -> None:
    reply = bytes.fromhex(reply_hex)
    if kind == "function":
        reply = build_frame(1, bytes.fromhex("04 02 00 03"))
    with pytest.raises(BadReply) as caught:
        check_reply(bytes.fromhex("01 03 00 04 00 02 85 CA"), reply)
    assert caught.value.kind == kind


def test_reply_from_another_address_is_refused() -> None:
    wrong = build_frame(2, bytes.fromhex("03 04 13 88 00 00"))
    with pytest.raises(BadReply) as caught:
        check_reply(bytes.fromhex("01 03 00 04 00 02 85 CA"), wrong)
    assert caught.value.kind == "address"


def test_exception_pdu() -> None:
    assert exception_pdu(0x06, 0x04) == bytes.fromhex("86 04")
    assert exception_pdu(0x03, 0x0B) == bytes.fromhex("83 0B")


def test_mbap_round_trip() -> None:
    adu = build_adu(0x1234, 7, bytes.fromhex("03 21 00 00 01"))
    assert adu == bytes.fromhex("12 34 00 00 00 06 07 03 21 00 00 01")
    header = parse_header(adu[:7])
    assert (header.transaction_id, header.unit_id, header.pdu_length) == (0x1234, 7, 5)


@pytest.mark.parametrize(
    "header_hex",
    [
        "00 01 00 01 00 06 01",  # protocol id 1
        "00 01 00 00 00 01 01",  # length 1: no PDU
        "00 01 00 00 00 00 01",  # length 0
        "00 01 00 00 00 FF 01",  # length 255: PDU over 253 bytes
        "00 01 00 00 FF FF 01",
    ],
)
def test_malformed_mbap_headers(header_hex: str) -> None:
    with pytest.raises(MalformedFrame):
        parse_header(bytes.fromhex(header_hex))


@pytest.mark.parametrize(
    ("request_pdu", "reply_pdu"),
    [
        ("03 07 1B 00 06", "03 02 00 23"),  # six words asked, one came: an earlier read's answer
        ("06 00 05 00 DE", "06 00 05 00 6F"),  # a write echoed with another value
        ("06 00 06 00 DE", "06 00 05 00 DE"),  # ... or another address
        ("10 00 0B 00 02 04 00 64 00 C8", "10 00 0B 00 03"),
        ("01 00 00 00 10", "01 01 AA"),  # 16 coils are 2 bytes
    ],
)
def test_a_reply_that_does_not_fit_the_request_is_refused(request_pdu: str, reply_pdu: str) -> None:
    request = build_frame(1, bytes.fromhex(request_pdu))
    with pytest.raises(BadReply) as caught:
        check_reply(request, build_frame(1, bytes.fromhex(reply_pdu)))
    assert caught.value.kind == "mismatch"


def test_exceptions_and_unusual_requests_pass() -> None:
    request = build_frame(1, bytes.fromhex("03 00 04 00 02"))
    assert check_reply(request, build_frame(1, bytes.fromhex("83 02"))) == bytes.fromhex("83 02")
    odd = build_frame(1, bytes.fromhex("41 01 02"))  # a vendor function: nothing to check
    assert check_reply(odd, build_frame(1, bytes.fromhex("41 09"))) == bytes.fromhex("41 09")
