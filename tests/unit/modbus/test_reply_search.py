"""Finding a reply among the bytes a real line delivers: pure bytes, no port.

Frames from PROTOCOL.md's table (CRC-verified there), with what real hardware puts before them.
"""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from gateway.modbus.crc import crc_bytes
from gateway.modbus.reply_search import Found, echo_passes_for_reply, search_reply
from gateway.modbus.rtu import build_frame

READ_REQUEST = bytes.fromhex("01 03 21 00 00 01 8E 36")  # state word 1 of drive 1
READ_REPLY = bytes.fromhex("01 03 02 00 03 F8 45")  # 0003H: stopped
WRITE_REQUEST = build_frame(1, bytes.fromhex("06 20 00 00 05"))  # stop
WRITE_EXCEPTION = build_frame(1, bytes.fromhex("86 04"))


def test_a_clean_reply_is_found_where_it_starts() -> None:
    search = search_reply(READ_REPLY, READ_REQUEST)
    assert (search.found, search.start, search.end, search.garbage) == (Found.COMPLETE, 0, 7, 0)


def test_a_glitch_byte_before_the_reply_is_skipped_and_counted() -> None:
    for glitch in (b"\x00", b"\xff", b"\x00\xff"):
        search = search_reply(glitch + READ_REPLY, READ_REQUEST)
        assert search.found is Found.COMPLETE
        assert (search.start, search.garbage) == (len(glitch), len(glitch))


def test_a_glitch_that_looks_like_the_start_of_the_reply_is_skipped_by_its_crc() -> None:
    # Drive 3, function 03: a glitch byte 03 reads as "address 3, function 3, 3 bytes".
    request = build_frame(3, bytes.fromhex("03 21 00 00 01"))
    reply = build_frame(3, bytes.fromhex("03 02 00 03"))
    search = search_reply(b"\x03" + reply, request)
    assert (search.found, search.start, search.end) == (Found.COMPLETE, 1, 1 + len(reply))


def test_a_partial_reply_says_where_it_will_end() -> None:
    search = search_reply(b"\xff" + READ_REPLY[:4], READ_REQUEST)
    assert (search.found, search.start, search.end) == (Found.PARTIAL, 1, 8)
    header_only = search_reply(READ_REPLY[:2], READ_REQUEST)
    assert (header_only.found, header_only.end) == (Found.PARTIAL, 0)


def test_only_garbage_is_nothing() -> None:
    search = search_reply(b"\x00\xff\x55", READ_REQUEST)
    assert (search.found, search.garbage) == (Found.NOTHING, 3)


def test_a_foreign_reply_is_reported_not_skipped() -> None:
    # Drive 2's well-formed reply to a request for drive 1: the bus must refuse it as such.
    foreign = build_frame(2, bytes.fromhex("03 02 00 03"))
    search = search_reply(foreign, READ_REQUEST)
    assert (search.found, search.start, search.end) == (Found.COMPLETE, 0, len(foreign))


def test_a_reply_with_a_bad_crc_is_corrupt() -> None:
    spoilt = READ_REPLY[:-1] + bytes((READ_REPLY[-1] ^ 0xFF,))
    assert search_reply(spoilt, READ_REQUEST).found is Found.CORRUPT


def test_the_echo_of_a_read_is_never_the_reply() -> None:
    search = search_reply(READ_REQUEST + READ_REPLY, READ_REQUEST)
    assert search.found is Found.COMPLETE
    assert (search.echo, search.start, search.garbage) == (8, 8, 0)
    # The echo alone: no reply yet.
    alone = search_reply(READ_REQUEST, READ_REQUEST)
    assert alone.found is Found.NOTHING
    assert alone.echo == 8


def test_an_echo_arriving_in_pieces_is_waited_for_never_taken_for_a_reply() -> None:
    # 03H from 0003H: the echo's third byte (the address's high byte, 00) reads as a byte
    # count of 0, so its first five bytes look like a whole (corrupt) reply. They are the
    # adapter's echo still arriving: wait for the rest, then find the reply after it.
    request = build_frame(1, bytes.fromhex("0300030002"))
    reply = build_frame(1, bytes.fromhex("0304000A0014"))
    for n in range(1, len(request)):
        assert search_reply(request[:n], request).found is Found.PARTIAL
    assert search_reply(request, request).found is Found.NOTHING  # the echo, whole
    both = request + reply
    for n in range(len(request) + 1, len(both)):
        assert search_reply(both[:n], request).found is Found.PARTIAL  # the reply, coming
    search = search_reply(both, request)
    assert (search.found, search.echo, search.start) == (Found.COMPLETE, 8, 8)


def test_a_reply_that_starts_like_the_request_is_still_taken_when_whole() -> None:
    # A 10H reply repeats the request's first six bytes; whole and sound, it is the reply even
    # though what came so far is shorter than the request.
    request = build_frame(1, bytes.fromhex("10200000020400010002"))
    reply = build_frame(1, bytes.fromhex("1020000002"))
    assert request[:6] == reply[:6]
    search = search_reply(reply, request)
    assert (search.found, search.start, search.end) == (Found.COMPLETE, 0, len(reply))


def test_the_echo_of_a_write_is_skipped_once_the_adapter_is_known_to_echo() -> None:
    # 06H's reply repeats the request byte for byte: only knowing the adapter tells them apart.
    assert echo_passes_for_reply(WRITE_REQUEST)
    assert not echo_passes_for_reply(READ_REQUEST)
    taken = search_reply(WRITE_REQUEST + WRITE_EXCEPTION, WRITE_REQUEST)
    assert (taken.found, taken.start) == (Found.COMPLETE, 0)
    known = search_reply(WRITE_REQUEST + WRITE_EXCEPTION, WRITE_REQUEST, adapter_echoes=True)
    assert (known.found, known.start, known.end) == (Found.COMPLETE, 8, 13)


def test_after_skips_a_candidate_that_never_completed() -> None:
    # 01 03 20 looked like the start of a 37-byte reply, then the real one came: it is found
    # once the caller gives up on the first (at the response deadline), never before.
    received = b"\x01\x03\x20" + READ_REPLY
    assert search_reply(received, READ_REQUEST).found is Found.PARTIAL
    later = search_reply(received, READ_REQUEST, after=0)
    assert (later.found, later.start) == (Found.COMPLETE, 3)


@given(
    glitches=st.lists(st.sampled_from([0x00, 0xFF]), max_size=3),
    address=st.integers(1, 247),
    words=st.lists(st.integers(0, 0xFFFF), min_size=1, max_size=16),
    exception=st.booleans(),
)
def test_any_reply_after_glitches_is_found_whole(
    glitches: list[int], address: int, words: list[int], exception: bool
) -> None:
    request = build_frame(address, bytes((3, 0x30, 0x00, 0, len(words))))
    if exception:
        reply = build_frame(address, b"\x83\x02")
    else:
        data = b"".join(word.to_bytes(2, "big") for word in words)
        body = bytes((address, 3, len(data))) + data
        reply = body + crc_bytes(body)
    received = bytes(glitches) + reply + b"\x00"  # a trailing glitch stays for the next drain
    search = search_reply(received, request)
    assert search.found is Found.COMPLETE
    assert received[search.start : search.end] == reply
    assert search.garbage == len(glitches)
