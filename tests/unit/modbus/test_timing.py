"""Time on the serial line for a character format, as the manual and the Modbus serial spec give
it: 11 bits a character (start, 8 data, parity or a second stop bit, stop), t3.5 of 3.5
characters up to 19200 baud, and a fixed 1.75 ms above. And an RTU frame taken apart."""

from __future__ import annotations

import math

import pytest

from gateway.modbus.rtu import build_frame, split_frame
from gateway.modbus.timing import CharacterFormat


@pytest.mark.parametrize(
    ("parity", "stopbits", "bits"), [("E", 1, 11), ("O", 1, 11), ("N", 2, 11), ("N", 1, 10)]
)
def test_bits_per_character(parity: str, stopbits: int, bits: int) -> None:
    assert CharacterFormat(19200, parity, stopbits).bits_per_char == bits


@pytest.mark.parametrize(
    ("baudrate", "t35_ms"),
    [(9600, 4.0104), (19200, 2.0052), (38400, 1.75), (115200, 1.75)],
)
def test_t35_is_three_and_a_half_characters_up_to_19200_then_fixed(
    baudrate: int, t35_ms: float
) -> None:
    assert math.isclose(CharacterFormat(baudrate, "E").t35_s * 1000, t35_ms, rel_tol=1e-4)


def test_a_frame_takes_its_bytes_times_the_character_time_on_the_wire() -> None:
    # The manual's read of state word 1 (8 bytes) at the drive's default 19200 8E1: 4.58 ms.
    frame = bytes.fromhex("01 03 21 00 00 01 8E 36")
    assert math.isclose(CharacterFormat(19200).wire_time_s(len(frame)), 8 * 11 / 19200)


def test_a_frame_splits_back_into_its_address_and_pdu() -> None:
    pdu = bytes.fromhex("06 20 00 00 01")
    frame = bytes.fromhex("03 06 20 00 00 01 42 28")  # the manual's "forward run at drive 03"
    assert build_frame(3, pdu) == frame
    assert split_frame(frame) == (3, pdu)
