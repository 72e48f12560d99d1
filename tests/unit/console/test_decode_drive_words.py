"""The traffic monitor's lines, in the drive's own words: the examples the module promises, an
exception named, a long read cut to one line, and a device without a profile left in raw words."""

from __future__ import annotations

import struct

from gateway.console.decode import MAX_VALUES_SHOWN, describe, describe_request
from gateway.profile import get_profile

GD350 = get_profile("gd350")


def test_a_state_word_read_is_named_and_its_answer_put_in_words() -> None:
    # 2100H = state word 1; 3 = stopped (INVT manual, communication chapter).
    shown = describe(bytes.fromhex("03 2100 0001"), bytes.fromhex("03 02 0003"), GD350)
    assert shown == "read 2100H state word 1 → 0003H stopped"


def test_a_parameter_write_is_shown_scaled_in_its_unit() -> None:
    # P00.11 (ACC time 1) is kept in tenths of a second: 100 is 10.0 s.
    request = bytes.fromhex("06 000B 0064")
    assert describe(request, request, GD350) == "write P00.11 = 10.0 s → ok"
    assert describe(request, None, GD350) == "write P00.11 = 10.0 s"  # no answer (yet)


def test_a_command_write_names_the_command() -> None:
    request = bytes.fromhex("06 2000 0001")
    assert describe(request, request, GD350) == "write 2000H control word = 1 (run_forward) → ok"


def test_a_run_with_its_frequency_in_one_write_names_both_words() -> None:
    # The manual's own 10H frame: forward run and 10.00 Hz.
    request = bytes.fromhex("10 2000 0002 04 0001 03E8")
    assert describe_request(request, GD350) == (
        "write 2000H control word = 1 (run_forward), 2001H frequency setpoint = 10.00 Hz"
    )


def test_an_exception_is_named_with_its_code() -> None:
    shown = describe(bytes.fromhex("03 2100 0001"), bytes.fromhex("83 02"), GD350)
    assert shown.endswith("→ exception 02H illegal_data_address")


def test_the_probes_loop_back_is_echoed_or_shown_as_it_came() -> None:
    probe = bytes.fromhex("08 0000 0000")
    assert describe(probe, probe, GD350) == "loop-back 08H → echoed"
    assert describe(probe, bytes.fromhex("08 0000 0001"), GD350) == (
        "loop-back 08H → 08 00 00 00 01"
    )


def test_a_long_read_names_its_first_values_and_counts_the_rest() -> None:
    count = 12
    reply = struct.pack(f">BB{count}H", 3, 2 * count, *range(count))
    shown = describe(struct.pack(">BHH", 3, 0x3000, count), reply, GD350)
    assert shown.startswith("read 3000H running frequency … 300BH (12 words) → 3000H ")
    assert shown.endswith(f", +{count - MAX_VALUES_SHOWN} more")
    assert shown.count(", ") == MAX_VALUES_SHOWN  # four values, then the count of the rest


def test_without_a_profile_addresses_and_raw_words_are_kept() -> None:
    request = bytes.fromhex("03 0010 0002")
    reply = bytes.fromhex("03 04 0007 0008")
    assert describe(request, reply, get_profile("generic")) == (
        "read 0010H … 0011H (2 words) → 0007H, 0008H"
    )
    assert describe(request, reply, None) == "read 0010H … 0011H (2 words) → 0007H, 0008H"


def test_what_it_cannot_read_it_says_so_without_failing() -> None:
    assert describe_request(b"", GD350) == "empty request"
    assert describe_request(bytes([0x2B, 0x0E, 0x01, 0x00]), GD350) == "function 2BH"
    assert describe(b"", bytes.fromhex("83 02"), GD350).startswith("empty request → exception")
