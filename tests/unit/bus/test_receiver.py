"""One line's receive buffer (`Receiver`), fed bytes as the port's reader callback feeds them: the
line's last sound, the reply found behind a glitch or the adapter's echo (each counted, the echo
told once in the log), a babbling line that can't fill memory, sound frames among bytes thrown
away handed to the ledger, a reply that stops short or never comes, and bursts measured."""

from __future__ import annotations

import logging
import time

import pytest

from gateway.bus.exchange import Stray
from gateway.bus.line_settings import LineSettings
from gateway.bus.receiver import MAX_BUFFERED, Receiver
from gateway.errors import BadReply, ReplyTimeout
from gateway.modbus.reply_search import Found
from gateway.modbus.rtu import build_frame
from gateway.modbus.timing import CharacterFormat
from tests.support import read_pdu, write_pdu

REQUEST = build_frame(1, read_pdu(0x2100))
REPLY = build_frame(1, bytes.fromhex("03 02 00 03"))
WRITE = build_frame(1, write_pdu(0x2001, 2500))
"""A 06H write: its normal reply is a copy of it, as the adapter's echo is."""


def receiver(baudrate: int = 1200, virtual: bool = False) -> Receiver:
    """At 1200 baud an 8-byte request takes 73 ms to cross the wire: a copy of it that comes
    within microseconds is the adapter's echo, however busy the machine."""
    char_format = CharacterFormat(baudrate, "E", 1)
    settings = LineSettings(
        "/dev/ttyUSB0", char_format, char_format.t35_s, 0.02, 0.05, 0.1, name="line1"
    )
    heard = Receiver(settings)
    heard.opened(virtual)
    return heard


def awaiting_reply(heard: Receiver, sent: float) -> None:
    """A request's last bit left at `sent`: its reply is awaited (arrivals recorded)."""
    heard.arrivals = [(len(heard.received), sent)]


def test_every_read_is_kept_and_stamps_the_lines_last_sound() -> None:
    heard = receiver()
    before = time.monotonic()
    heard.take(REPLY[:3])
    heard.take(REPLY[3:])
    assert bytes(heard.received) == REPLY
    assert heard.quiet_since >= before


def test_a_glitch_before_a_reply_is_skipped_and_counted() -> None:
    heard = receiver()
    awaiting_reply(heard, time.monotonic())
    heard.take(b"\x00" + REPLY)
    search = heard.search(REQUEST, heard.echo_deadline(REQUEST, time.monotonic()))
    assert search.found is Found.COMPLETE
    assert heard.take_reply(search, search.end) == REPLY
    assert heard.garbage_bytes == 1
    assert heard.echoes == 0
    assert not heard.received


def test_the_adapters_echo_is_never_taken_for_the_reply_and_is_told_once(
    caplog: pytest.LogCaptureFixture,
) -> None:
    heard = receiver()
    for _ in range(2):
        sent = time.monotonic()
        awaiting_reply(heard, sent)
        heard.take(WRITE)  # the echo, at once: long before the request could cross the wire
        heard.take(WRITE)  # the drive's acknowledgement, a copy too
        search = heard.search(WRITE, heard.echo_deadline(WRITE, sent))
        assert search.found is Found.COMPLETE
        assert search.start == len(WRITE)  # the second copy
        assert heard.take_reply(search, search.end) == WRITE
        assert not heard.received
    assert heard.echoes == 2
    assert heard.echo_detected
    hints = [r for r in caplog.records if "echoes what the gateway sends" in r.getMessage()]
    assert len(hints) == 1
    assert hints[0].levelno == logging.WARNING
    assert "set `echo: true` for this bus" in hints[0].getMessage()


def test_on_a_pty_a_copy_of_the_request_that_comes_at_once_is_the_reply() -> None:
    """A virtual line has no wire: its peer may answer at once, and timing tells nothing."""
    heard = receiver(virtual=True)
    sent = time.monotonic()
    awaiting_reply(heard, sent)
    heard.take(WRITE)
    assert heard.echo_deadline(WRITE, sent) == 0.0
    search = heard.search(WRITE, heard.echo_deadline(WRITE, sent))
    assert (search.found, search.start) == (Found.COMPLETE, 0)
    assert heard.take_reply(search, search.end) == WRITE
    assert heard.echoes == 0


def test_a_babbling_line_keeps_no_more_than_the_buffer_holds() -> None:
    heard = receiver()
    awaiting_reply(heard, time.monotonic())
    heard.take(b"\x55" * (MAX_BUFFERED + 1000))
    assert len(heard.received) == MAX_BUFFERED
    assert heard.discarded_bytes == 1000
    # Offsets moved: the silence measure starts again, from this read.
    assert heard.arrivals == [(MAX_BUFFERED, heard.quiet_since)]
    heard.take(b"\x55" * 10)
    assert len(heard.received) == MAX_BUFFERED
    assert heard.discarded_bytes == 1010


def test_sound_frames_among_bytes_thrown_away_go_to_the_ledger_with_when_they_came() -> None:
    heard = receiver()
    told: list[tuple[Stray, ...]] = []
    first = b"\xff" + REPLY + b"\x00\x00"
    heard.take(first)  # thrown away without anyone to tell
    heard.discard()
    assert heard.discarded_bytes == len(first)
    heard.on_set_aside = told.append
    other = build_frame(2, bytes.fromhex("03 02 00 01"))
    second = b"\xff" + REPLY + b"\x00" + other
    heard.take(second)
    heard.discard()
    assert told == [((REPLY, heard.quiet_since), (other, heard.quiet_since))]
    assert not heard.received
    heard.take(b"\x00\xff\x00")  # noise alone: nothing to tell
    heard.discard()
    assert len(told) == 1
    heard.discard()  # nothing there: nothing counted
    assert heard.discarded_bytes == len(first) + len(second) + 3


def test_a_reply_that_stops_short_fails_as_truncated_with_what_came() -> None:
    heard = receiver()
    awaiting_reply(heard, time.monotonic())
    heard.take(REPLY[:5])
    search = heard.search(REQUEST, 0.0)
    assert search.found is Found.PARTIAL
    with pytest.raises(BadReply) as failed:
        heard.reply_at_deadline(REQUEST, search)
    assert failed.value.kind == "truncated"
    assert failed.value.frame == REPLY[:5]


def test_bytes_that_are_no_reply_fail_as_noise_but_a_glitch_alone_is_a_timeout() -> None:
    heard = receiver()
    heard.take(b"\x00\xff\x00\xff\x00\xff")
    search = heard.search(REQUEST, 0.0)
    assert search.found is Found.NOTHING
    with pytest.raises(BadReply) as failed:
        heard.reply_at_deadline(REQUEST, search)
    assert failed.value.kind == "noise"
    heard.received.clear()
    heard.take(b"\x00")
    with pytest.raises(ReplyTimeout):
        heard.reply_at_deadline(REQUEST, heard.search(REQUEST, 0.0))


def test_a_silence_inside_a_reply_is_measured_and_bursts_are_told_once(
    caplog: pytest.LogCaptureFixture,
) -> None:
    heard = receiver(baudrate=115200)
    for pause_s in (0.02, 0.03):
        awaiting_reply(heard, time.monotonic())
        heard.take(REPLY[:3])
        time.sleep(pause_s)  # the adapter holds the rest back (a latency timer)
        heard.take(REPLY[3:])
        search = heard.search(REQUEST, 0.0)
        assert heard.take_reply(search, search.end) == REPLY
        assert heard.longest_reply_silence_s >= pause_s - heard.settings.char_format.wire_time_s(4)
    assert heard.longest_reply_silence_s < 1.0
    bursts = [r for r in caplog.records if "replies arrive in bursts" in r.getMessage()]
    assert len(bursts) == 1
    assert "bus line1 (/dev/ttyUSB0)" in bursts[0].getMessage()


def test_a_reply_in_one_piece_shows_no_silence() -> None:
    heard = receiver(baudrate=115200)
    awaiting_reply(heard, time.monotonic() - 1.0)  # however long the drive took to answer
    heard.take(REPLY)
    search = heard.search(REQUEST, 0.0)
    assert heard.take_reply(search, search.end) == REPLY
    assert heard.longest_reply_silence_s == 0.0
