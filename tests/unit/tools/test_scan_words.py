"""What a scan says of each drive it found, from its four status words, in the manual's words;
and what to check when it found none."""

from __future__ import annotations

from gateway.tools.masters import SerialOptions
from gateway.tools.report import no_drive_found
from gateway.tools.scan import FoundDrive, ScanResult

GD350 = 0x01A0
GD300_OR_LIFT = 0x010A
"""Both the GD300 and the GD300-LIFT answer 010AH at 2103H."""
STOPPED = 3
CE = 18
"""RS-485 communication fault (the manual's fault table)."""


def test_a_drive_is_named_with_its_state_fault_and_command_source() -> None:
    drive = FoundDrive(1, GD350, STOPPED, 0, CE)
    assert drive.model == "GD350"
    assert drive.profile is not None
    assert drive.profile.key == "gd350"
    assert drive.state == "stopped"
    assert drive.fault_text == "CE: RS-485 communication fault"
    assert drive.command_source == "keypad"  # state word 2, bits 6-7 clear


def test_a_code_two_series_share_names_both_and_still_reads_the_fault() -> None:
    drive = FoundDrive(2, GD300_OR_LIFT, STOPPED, 0, CE)
    assert drive.model == "GD300 or GD300-LIFT"
    assert drive.profile is None
    assert drive.fault_text == "CE: RS-485 communication fault"


def test_what_a_drive_did_not_say_is_shown_as_a_dash() -> None:
    drive = FoundDrive(3)
    assert (drive.model, drive.state, drive.fault_text, drive.command_source) == (
        "unknown",
        "-",
        "-",
        "-",
    )


def test_no_drive_found_points_at_the_settings_or_at_the_garbage_that_came() -> None:
    options = SerialOptions(port="/dev/ttyUSB0", baudrate=19200, parity="E", timeout_s=0.05)
    silent = no_drive_found(options, ScanResult())
    assert silent.message.startswith("no drive answered on /dev/ttyUSB0")
    assert any("P14.01" in check for check in silent.checks)  # the drive's baud rate
    assert any("P14.03" in check and "50 ms" in check for check in silent.checks)
    garbled = no_drive_found(options, ScanResult(garbled=[3, 4]))
    assert "garbled replies came at address 3, 4" in garbled.message
    assert any("termination" in check for check in garbled.checks)
