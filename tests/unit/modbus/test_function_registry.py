"""The function-code registry, as bytes: reply lengths, request checks, fits, splits. No I/O.

Example frames follow the Modbus application protocol V1.1b3's own examples where it has them.
"""

from __future__ import annotations

import struct

import pytest
from hypothesis import given
from hypothesis import strategies as st

from gateway.errors import ExceptionCode
from gateway.modbus.functions import (
    FUNCTIONS,
    NEED_MORE,
    UNKNOWN_LENGTH,
    Reason,
    changes_nothing,
    check_request,
    front_door,
    join_replies,
    lookup,
    needs_split,
    rtu_reply_length,
    split_request,
)
from gateway.modbus.rtu import build_frame

ADDRESS = 0x11


def read_as_the_line_does(stream: bytes, request_length: int, chunk: int = 256) -> bytes | None:
    """Take bytes off `stream` the way the line does: never more than the length rule asks for,
    asking again after every read; None when the rule says the reply ends on silence."""
    reply = b""
    while True:
        length = rtu_reply_length(reply, request_length)
        if length == UNKNOWN_LENGTH:
            return None
        if length == NEED_MORE:
            want = 1
        elif len(reply) >= length:
            return reply
        else:
            want = min(chunk, length - len(reply))
        assert len(reply) + want <= len(stream), "asked for more than the reply holds"
        reply += stream[len(reply) : len(reply) + want]


def device_identification(*objects: bytes, more_follows: int = 0x00) -> bytes:
    body = b"".join(
        bytes((object_id, len(value))) + value for object_id, value in enumerate(objects)
    )
    return bytes((0x2B, 0x0E, 0x01, 0x01, more_follows, 0x00, len(objects))) + body


# (request PDU, a normal reply PDU to it), one per known code.
EXCHANGES = {
    0x01: ("01 00 13 00 13", "01 03 CD 6B 05"),
    0x02: ("02 00 C4 00 16", "02 03 AC DB 35"),
    0x03: ("03 00 6B 00 03", "03 06 02 2B 00 00 00 64"),
    0x04: ("04 00 08 00 01", "04 02 00 0A"),
    0x05: ("05 00 AC FF 00", "05 00 AC FF 00"),
    0x06: ("06 00 01 00 03", "06 00 01 00 03"),
    0x07: ("07", "07 6D"),
    0x08: ("08 00 00 A5 37", "08 00 00 A5 37"),
    0x0B: ("0B", "0B FF FF 01 08"),
    0x0C: ("0C", "0C 08 00 00 01 08 01 21 20 00"),
    0x0F: ("0F 00 13 00 0A 02 CD 01", "0F 00 13 00 0A"),
    0x10: ("10 00 01 00 02 04 00 0A 01 02", "10 00 01 00 02"),
    0x11: ("11", "11 03 42 FF 01"),
    0x14: (
        "14 0E 06 00 04 00 01 00 02 06 00 03 00 09 00 02",
        "14 0C 05 06 0D FE 00 20 05 06 33 CD 00 40",
    ),
    0x15: (
        "15 0D 06 00 04 00 07 00 03 06 AF 04 BE 10 0D",
        "15 0D 06 00 04 00 07 00 03 06 AF 04 BE 10 0D",
    ),
    0x16: ("16 00 04 00 F2 00 25", "16 00 04 00 F2 00 25"),
    0x17: (
        "17 00 03 00 06 00 0E 00 03 06 00 FF 00 FF 00 FF",
        "17 0C 00 FE 0A CD 00 01 00 03 00 0D 00 FF",
    ),
    0x18: ("18 04 DE", "18 00 06 00 02 01 B8 12 84"),
    0x2B: ("2B 0E 01 00", device_identification(b"INVT", b"GD350", b"V1.40").hex(" ")),
}


def pdu(text: str) -> bytes:
    return bytes.fromhex(text)


def test_every_known_code_has_an_example() -> None:
    assert sorted(EXCHANGES) == sorted(FUNCTIONS)


# -- reply lengths --------------------------------------------------------------------------------


@pytest.mark.parametrize("code", sorted(EXCHANGES), ids=lambda c: f"{c:02X}H")
def test_every_known_reply_ends_at_its_last_byte(code: int) -> None:
    request_hex, reply_hex = EXCHANGES[code]
    request = build_frame(ADDRESS, pdu(request_hex))
    reply = build_frame(ADDRESS, pdu(reply_hex))
    # Followed on the line by whatever comes next: none of it may be taken into the reply.
    assert read_as_the_line_does(reply + b"\xff" * 300, len(request)) == reply
    assert read_as_the_line_does(reply + b"\xff" * 300, len(request), chunk=1) == reply


def test_the_header_is_needed_before_the_length_is_known() -> None:
    read = build_frame(ADDRESS, pdu("03 02 00 07"))
    assert rtu_reply_length(read[:1], 8) == NEED_MORE
    assert rtu_reply_length(read[:2], 8) == NEED_MORE  # the byte count is still to come
    assert rtu_reply_length(read[:3], 8) == len(read) == 7
    assert rtu_reply_length(bytes((ADDRESS, 0x06)), 8) == 8  # fixed: the code is enough
    assert rtu_reply_length(bytes((ADDRESS, 0x08)), 11) == 11  # 08H echoes the request
    assert rtu_reply_length(bytes((ADDRESS, 0x16)), 10) == 10


def test_an_exception_reply_is_five_bytes_whatever_the_function() -> None:
    for function in (0x01, 0x03, 0x08, 0x18, 0x2B, 0x41):
        assert rtu_reply_length(bytes((ADDRESS, function | 0x80)), 8) == 5


def test_18h_counts_its_bytes_in_two() -> None:
    reply = build_frame(ADDRESS, pdu(EXCHANGES[0x18][1]))
    assert rtu_reply_length(reply[:2], 5) == NEED_MORE
    assert rtu_reply_length(reply[:3], 5) == 4  # a step: the count's second byte
    assert rtu_reply_length(reply[:4], 5) == len(reply) == 12
    long_count = build_frame(ADDRESS, pdu("18 01 02"))  # 258 bytes of FIFO: no RTU frame
    assert rtu_reply_length(long_count, 5) == UNKNOWN_LENGTH


def test_2bh_0eh_is_parsed_object_by_object() -> None:
    reply = build_frame(ADDRESS, device_identification(b"INVT", b"GD350"))
    assert rtu_reply_length(reply[:2], 6) == NEED_MORE
    assert rtu_reply_length(reply[:3], 6) == 8  # up to the number of objects
    assert rtu_reply_length(reply[:8], 6) == 10  # the first object's id and length
    assert rtu_reply_length(reply[:10], 6) == 10 + 4 + 2  # past "INVT" to the second's
    assert rtu_reply_length(reply[:16], 6) == len(reply) == 16 + 5 + 2
    empty = build_frame(ADDRESS, device_identification())
    assert rtu_reply_length(empty[:8], 6) == len(empty) == 10


def test_2bh_0eh_more_follows_is_still_one_frame() -> None:
    reply = build_frame(ADDRESS, device_identification(b"x" * 200, more_follows=0xFF))
    assert read_as_the_line_does(reply, 6) == reply


def test_what_the_registry_cannot_size_ends_on_silence() -> None:
    assert rtu_reply_length(bytes((ADDRESS, 0x41, 0x00)), 8) == UNKNOWN_LENGTH  # a vendor's
    canopen = build_frame(ADDRESS, pdu("2B 0D 00 01 02"))  # 2BH, but not 0EH
    assert rtu_reply_length(canopen[:3], 6) == UNKNOWN_LENGTH
    objects_past_a_frame = build_frame(ADDRESS, pdu("2B 0E 01 01 00 00 02 00 FF"))
    assert rtu_reply_length(objects_past_a_frame + bytes(255), 6) == UNKNOWN_LENGTH


@given(st.sampled_from(sorted(EXCHANGES)), st.binary(max_size=270), st.integers(4, 256))
def test_a_length_once_reached_is_final(code: int, tail: bytes, request_length: int) -> None:
    """Whatever the bytes, a length the reader has reached never changes with more bytes, and one
    not yet reached is ahead of it: a reader that asks again after each read never overshoots."""
    mei = b"\x0e" if code == 0x2B else b""  # 2BH's other MEI types end on silence
    data = bytes((ADDRESS, code)) + mei + tail
    final: int | None = None
    for end in range(len(data) + 1):
        length = rtu_reply_length(data[:end], request_length)
        if final is not None:
            assert length == final
        elif length not in (NEED_MORE, UNKNOWN_LENGTH):
            assert 4 <= length <= 260
            if end >= length:
                final = length


# -- request checks -------------------------------------------------------------------------------

WELL_FORMED = [request for request, _ in EXCHANGES.values()] + [
    "01 00 00 07 D0",  # 2000 coils
    "03 00 00 00 7D",  # 125 registers
    "05 00 01 00 00",  # coil off
    "08 00 01 00 00",  # restart communications: a sub-function the device judges
    "0F 00 00 07 B0 F6" + " FF" * 246,  # 1968 coils in 246 bytes
    "10 00 00 00 7B F6" + " 00" * 246,  # 123 registers
    "2B 0E 04 05",  # one specific object
    "2B 0D 00 01 02",  # CANopen: the device's to judge
    "41 01 02 03",  # a vendor's code
]

MALFORMED = [
    ("", Reason.LENGTH),
    ("00 00 01", Reason.FUNCTION_CODE),
    ("83 00 00 00 01", Reason.FUNCTION_CODE),
    ("03 00 00 00", Reason.LENGTH),
    ("03 00 00 00 01 00", Reason.LENGTH),
    ("03 00 00 00 00", Reason.QUANTITY),
    ("03 00 00 00 7E", Reason.QUANTITY),  # 126 registers
    ("04 00 00 00 7E", Reason.QUANTITY),
    ("01 00 00 07 D1", Reason.QUANTITY),  # 2001 coils
    ("02 00 00 00 00", Reason.QUANTITY),
    ("05 00 01 12 34", Reason.VALUE),
    ("05 00 01 FF", Reason.LENGTH),
    ("06 00 01 00", Reason.LENGTH),
    ("07 00", Reason.LENGTH),
    ("08 00", Reason.LENGTH),
    ("0B 00", Reason.LENGTH),
    ("0C 00", Reason.LENGTH),
    ("0F 00 00 07 B1 F7" + " FF" * 247, Reason.QUANTITY),  # 1969 coils
    ("0F 00 13 00 0A 01 CD", Reason.BYTE_COUNT),  # 10 coils need 2 bytes
    ("0F 00 13 00 0A 02 CD", Reason.BYTE_COUNT),  # ...and carry them
    ("0F 00 13 00", Reason.LENGTH),
    ("10 00 00 00 7C F8 00 00", Reason.QUANTITY),  # 124 registers
    ("10 00 00 00 00 00", Reason.QUANTITY),
    ("10 00 01 00 02 03 00 0A 01", Reason.BYTE_COUNT),
    ("10 00 01 00 02 04 00 0A 01", Reason.BYTE_COUNT),
    ("11 00", Reason.LENGTH),
    ("14 06 06 00 04 00 01 00", Reason.BYTE_COUNT),  # below 7
    ("14 08 06 00 04 00 01 00 02 06", Reason.BYTE_COUNT),  # not whole sub-requests
    ("14 07 06 00 04 00 01 00", Reason.BYTE_COUNT),  # one byte short
    ("15 08 06 00 04 00 07 00 03 06", Reason.BYTE_COUNT),  # below 9
    ("16 00 04 00 F2 00", Reason.LENGTH),
    ("17 00 03 00 7E 00 0E 00 01 02 00 FF", Reason.QUANTITY),  # reads 126
    ("17 00 03 00 06 00 0E 00 7A F4 00 00", Reason.QUANTITY),  # writes 122
    ("17 00 03 00 06 00 0E 00 03 04 00 FF 00 FF 00 FF", Reason.BYTE_COUNT),
    ("17 00 03 00 06 00 0E 00 03", Reason.LENGTH),
    ("18 04", Reason.LENGTH),
    ("18 04 DE 00", Reason.LENGTH),
    ("2B", Reason.LENGTH),
    ("2B 0E 01", Reason.LENGTH),
    ("2B 0E 05 00", Reason.VALUE),
    ("2B 0E 00 00", Reason.VALUE),
    ("41" + " 00" * 253, Reason.LENGTH),  # over 253 bytes, whatever the code
]


@pytest.mark.parametrize("request_hex", WELL_FORMED)
def test_well_formed_requests_pass(request_hex: str) -> None:
    assert check_request(pdu(request_hex)) is None


@pytest.mark.parametrize(
    ("request_hex", "reason"), MALFORMED, ids=[f"{m[0][:8]}-{m[1]}" for m in MALFORMED]
)
def test_malformed_requests_say_why(request_hex: str, reason: Reason) -> None:
    malformed = check_request(pdu(request_hex))
    assert malformed is not None
    assert malformed.reason is reason
    assert malformed.detail


def test_every_reason_has_an_example() -> None:
    assert {reason for _, reason in MALFORMED} == set(Reason)


def test_a_front_door_answers_01h_for_no_function_code_and_03h_for_the_rest() -> None:
    not_a_function = check_request(pdu("00"))
    assert not_a_function is not None
    assert not_a_function.exception_code is ExceptionCode.ILLEGAL_FUNCTION
    too_many = check_request(pdu("03 00 00 00 7E"))
    assert too_many is not None
    assert too_many.exception_code is ExceptionCode.ILLEGAL_DATA_VALUE
    assert too_many.detail == "quantity 126 outside 1..125"


@given(
    st.sampled_from([(0x01, 2000), (0x02, 2000), (0x03, 125), (0x04, 125)]), st.integers(0, 0xFFFF)
)
def test_block_reads_take_the_spec_quantities(limit: tuple[int, int], quantity: int) -> None:
    function, most = limit
    malformed = check_request(struct.pack(">BHH", function, 0, quantity))
    assert (malformed is None) == (1 <= quantity <= most)


@given(
    st.sampled_from([(0x0F, 1968, 8), (0x10, 123, 2)]),
    st.integers(0, 2100),
    st.integers(0, 255),
)
def test_block_writes_count_their_bytes(
    limit: tuple[int, int, int], quantity: int, count: int
) -> None:
    function, most, per_byte = limit
    needed = (quantity + 7) // 8 if per_byte == 8 else 2 * quantity
    request = struct.pack(">BHHB", function, 0, quantity, count) + bytes(min(count, 247))
    malformed = check_request(request[:253])
    valid = 1 <= quantity <= most and count == needed
    assert (malformed is None) == valid
    if not valid:
        assert malformed is not None
        assert malformed.reason in {Reason.QUANTITY, Reason.BYTE_COUNT, Reason.LENGTH}


@given(st.binary(max_size=300))
def test_any_bytes_are_well_formed_or_have_a_reason(data: bytes) -> None:
    malformed = check_request(data)
    assert malformed is None or isinstance(malformed.reason, Reason)


# -- fits, properties, splits ---------------------------------------------------------------------


@pytest.mark.parametrize("code", sorted(EXCHANGES), ids=lambda c: f"{c:02X}H")
def test_each_example_reply_fits_its_request(code: int) -> None:
    request_hex, reply_hex = EXCHANGES[code]
    assert lookup(code).fits(pdu(request_hex), pdu(reply_hex))


@pytest.mark.parametrize(
    ("request_hex", "late_reply_hex"),
    [
        ("03 00 6B 00 03", "03 04 02 2B 00 00"),  # 2 registers, 3 asked for
        ("01 00 13 00 13", "01 02 CD 6B"),
        ("06 00 01 00 03", "06 00 01 00 04"),
        ("10 00 01 00 02 04 00 0A 01 02", "10 00 02 00 02"),
        ("16 00 04 00 F2 00 25", "16 00 04 00 F2 00 26"),
        ("17 00 03 00 06 00 0E 00 03 06 00 FF 00 FF 00 FF", "17 02 00 FE"),
    ],
)
def test_a_reply_to_another_request_does_not_fit(request_hex: str, late_reply_hex: str) -> None:
    assert not lookup(pdu(request_hex)[0]).fits(pdu(request_hex), pdu(late_reply_hex))


def test_what_the_gateway_may_do_with_each_code() -> None:
    def codes(flag: str) -> list[int]:
        return sorted(c for c, f in FUNCTIONS.items() if getattr(f, flag))

    assert codes("writes") == [0x05, 0x06, 0x0F, 0x10, 0x15, 0x16, 0x17]
    assert codes("broadcastable") == [0x05, 0x06, 0x0F, 0x10, 0x16]
    assert codes("coalescable") == [0x01, 0x02, 0x03, 0x04]
    assert codes("split") == [0x03, 0x04, 0x10]
    with_registers = sorted(c for c, f in FUNCTIONS.items() if f.registers(bytes((c,))))
    assert with_registers == [0x03, 0x04, 0x06, 0x10, 0x16, 0x17]
    unknown = lookup(0x41)
    assert (unknown.writes, unknown.broadcastable, unknown.coalescable) == (False, False, False)
    assert unknown.split is None


def test_only_reads_and_the_loop_back_change_nothing() -> None:
    for code, (request_hex, _) in EXCHANGES.items():
        assert changes_nothing(pdu(request_hex)) == (not lookup(code).writes), f"{code:02X}H"
    assert not changes_nothing(pdu("08 00 01 00 00"))  # restart communications
    assert not changes_nothing(pdu("08 00 04 00 00"))  # listen only: the device goes silent
    assert not changes_nothing(pdu("41 00"))  # unknown: taken for a write


@given(
    st.sampled_from([0x03, 0x04, 0x10]),
    st.integers(0, 0xFFFF),
    st.integers(1, 125),
    st.integers(1, 16),
)
def test_a_split_covers_the_request_and_joins_to_its_reply(
    function: int, start: int, count: int, max_words: int
) -> None:
    values = [(start + i) & 0xFFFF for i in range(count)]
    if function == 0x10:
        request = struct.pack(f">BHHB{count}H", function, start, count, 2 * count, *values)
    else:
        request = struct.pack(">BHH", function, start, count)
    parts = split_request(request, max_words)
    if check_request(request) is not None or count <= max_words or start + count > 0x10000:
        assert parts is None
        return
    assert parts is not None
    covered: list[int] = []
    replies = []
    for part in parts:
        part_start, part_count = struct.unpack(">HH", part[1:5])
        assert 1 <= part_count <= max_words
        assert check_request(part) is None
        covered += range(part_start, part_start + part_count)
        if function == 0x10:
            assert (
                list(struct.unpack(f">{part_count}H", part[6:]))
                == values[part_start - start : part_start - start + part_count]
            )
            replies.append(part[:5])
        else:
            words = values[part_start - start : part_start - start + part_count]
            replies.append(struct.pack(f">BB{part_count}H", function, 2 * part_count, *words))
    assert covered == list(range(start, start + count))
    if function == 0x10:
        assert join_replies(request, replies) == request[:5]
    else:
        assert join_replies(request, replies) == struct.pack(
            f">BB{count}H", function, 2 * count, *values
        )


@given(
    st.sampled_from([0x03, 0x04]),
    st.integers(0, 0xFFFF),
    st.integers(1, 125),
    st.integers(1, 125),
)
def test_a_remembered_split_verdict_is_the_splits(
    function: int, start: int, count: int, max_words: int
) -> None:
    pdu = struct.pack(">BHH", function, start, count)
    expected = split_request(pdu, max_words) is not None
    assert needs_split(pdu, max_words) is expected
    assert needs_split(pdu, max_words) is expected  # the remembered answer too
    assert expected == (count > max_words and start + count <= 0x10000)


@given(
    st.one_of(
        st.binary(min_size=0, max_size=12),
        st.builds(
            lambda code, start, count: struct.pack(">BHH", code, start, count),
            st.sampled_from([1, 2, 3, 4, 5, 6, 0x41]),
            st.integers(0, 0xFFFF),
            st.integers(0, 0x200),
        ),
    )
)
def test_the_front_doors_one_lookup_says_what_the_two_checks_say(request_pdu: bytes) -> None:
    """`front_door`, the Modbus-TCP server's one remembered verdict per request, is exactly
    (`changes_nothing`, `check_request`) for any bytes a client may send."""
    if not request_pdu:
        return  # the server never takes an empty PDU (MIN_FRAME)
    assert front_door(request_pdu) == (changes_nothing(request_pdu), check_request(request_pdu))
