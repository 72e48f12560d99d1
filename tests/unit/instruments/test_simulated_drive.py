"""The simulated drive's logic, without a line: PDUs in, PDUs out, time passed in explicitly."""

from __future__ import annotations

import struct

import pytest

from gateway.instruments.simulator.drive import SimulatedDrive
from gateway.instruments.simulator.framing import RequestAssembler
from gateway.instruments.simulator.motor import Ramp
from gateway.profile import parse_parameter, ram_address
from tests.support import read_pdu as read
from tests.support import write_many
from tests.support import write_pdu as write

STOPPED, RUNNING_FORWARD, RUNNING_REVERSE, FAULT = 3, 1, 2, 4


def words(reply: bytes) -> list[int]:
    assert reply[0] == 0x03, f"exception {reply.hex(' ')}"
    return list(struct.unpack(f">{reply[1] // 2}H", reply[2:]))


def word(drive: SimulatedDrive, address: int, now: float) -> int:
    return words(drive.handle(read(address), now))[0]


def p(name: str) -> int:
    return parse_parameter(name)


@pytest.fixture
def drive() -> SimulatedDrive:
    """A GD350 at address 1 with a 1.0 s acceleration and 2.0 s deceleration time (50 Hz max)."""
    drive = SimulatedDrive(1)
    assert drive.handle(write_many(p("P00.11"), 10, 20), 0.0)[0] == 0x10
    return drive


# ---------------------------------------------------------------- run, ramp, stop


def test_run_ramps_up_at_max_frequency_over_acceleration_time(drive: SimulatedDrive) -> None:
    drive.handle(write(0x2001, 2500), 0.0)  # 25.00 Hz
    drive.handle(write(0x2000, 1), 0.0)  # forward run
    assert word(drive, 0x2100, 0.0) == RUNNING_FORWARD
    assert word(drive, 0x3000, 0.2) == 1000  # 50 Hz per 1.0 s: 10.00 Hz after 0.2 s
    assert word(drive, 0x3000, 0.5) == 2500  # reached and held
    assert word(drive, 0x3001, 0.5) == 2500
    assert word(drive, 0x3000, 3.0) == 2500


def test_stop_ramps_down_then_the_drive_reports_stopped(drive: SimulatedDrive) -> None:
    drive.handle(write_many(0x2000, 1, 5000), 0.0)  # run forward at 50.00 Hz
    assert word(drive, 0x3000, 1.0) == 5000
    drive.handle(write(0x2000, 5), 1.0)  # stop: 50 Hz per 2.0 s down
    assert word(drive, 0x3000, 1.5) == 3750
    assert word(drive, 0x2100, 1.5) == RUNNING_FORWARD  # still turning
    assert word(drive, 0x3000, 3.0) == 0
    assert word(drive, 0x2100, 3.0) == STOPPED


def test_coast_stop_drops_the_output_at_once(drive: SimulatedDrive) -> None:
    drive.handle(write_many(0x2000, 1, 5000), 0.0)
    drive.handle(write(0x2000, 6), 1.0)
    assert word(drive, 0x3000, 1.0) == 0
    assert word(drive, 0x2100, 1.0) == STOPPED


def test_reverse_run_goes_through_zero(drive: SimulatedDrive) -> None:
    drive.handle(write_many(0x2000, 1, 5000), 0.0)
    drive.handle(write(0x2000, 2), 1.0)  # reverse: decelerate 2.0 s to 0, accelerate 1.0 s
    assert word(drive, 0x2100, 1.0) == RUNNING_REVERSE
    assert drive.frequency_hz(2.0) == pytest.approx(25.0)
    assert drive.frequency_hz(3.5) == pytest.approx(-25.0)
    assert drive.frequency_hz(5.0) == pytest.approx(-50.0)
    assert word(drive, 0x3000, 5.0) == 5000  # 3000H shows the magnitude


def test_jog_runs_at_p08_06_and_jog_stop_ends_it() -> None:
    drive = SimulatedDrive(1)
    drive.handle(write_many(p("P08.07"), 0, 0), 0.0)  # instant jog ramps
    drive.handle(write(0x2000, 3), 0.0)
    assert word(drive, 0x3000, 0.1) == 500  # P08.06 default 5.00 Hz
    assert word(drive, 0x2100, 0.1) == RUNNING_FORWARD
    drive.handle(write(0x2000, 8), 0.2)
    assert word(drive, 0x2100, 0.3) == STOPPED


def test_setpoint_is_clamped_to_the_upper_limit(drive: SimulatedDrive) -> None:
    drive.handle(write(p("P00.03"), 10000), 0.0)  # max 100.00 Hz
    drive.handle(write_many(0x2000, 1, 8000), 0.0)  # ask for 80.00 Hz
    assert word(drive, 0x3000, 10.0) == 5000  # P00.04 upper limit: 50.00 Hz


def test_running_values_are_plausible_at_50_hz(drive: SimulatedDrive) -> None:
    drive.handle(write_many(0x2000, 1, 5000), 0.0)
    values = words(drive.handle(read(0x3000, 12), 5.0))
    frequency, setting, bus, volts, amps, rpm, power, torque = values[:8]
    assert (frequency, setting) == (5000, 5000)
    assert 5000 <= bus <= 5600  # about 540.0 V
    assert volts == 380
    assert 50 <= amps <= 150  # 5.0..15.0 A on a 10 A motor
    assert 1400 <= rpm < 1500  # 4-pole motor with slip
    assert 0 < power <= 1000
    assert 0 < torque <= 1000


def test_stopped_drive_shows_no_output(drive: SimulatedDrive) -> None:
    values = words(drive.handle(read(0x3000, 8), 1.0))
    assert values[0] == 0
    assert values[2] == 5400  # the DC bus is charged
    assert values[3:6] == [0, 0, 0]


def test_keypad_command_source_accepts_but_ignores_run(drive: SimulatedDrive) -> None:
    assert drive.handle(write(p("P00.01"), 0), 0.0) == write(p("P00.01"), 0)
    assert drive.handle(write(0x2000, 1), 0.0) == write(0x2000, 1)  # echoed ...
    assert word(drive, 0x2100, 1.0) == STOPPED  # ... but the motor doesn't start
    assert (word(drive, 0x2101, 1.0) >> 5) & 0b11 == 0  # command source: keypad
    drive.handle(write(p("P00.01"), 2), 1.0)
    assert (word(drive, 0x2101, 1.0) >> 5) & 0b11 == 0b10  # communication


# ---------------------------------------------------------------- faults


def test_injected_fault_trips_coasts_and_shifts_the_history(drive: SimulatedDrive) -> None:
    drive.set_fault_history([10, 11])
    drive.handle(write_many(0x2000, 1, 5000), 0.0)
    drive.inject_fault(35, now=2.0)
    assert word(drive, 0x2100, 2.0) == FAULT
    assert word(drive, 0x2102, 2.0) == 35
    assert word(drive, 0x5000, 2.0) == 35  # GD350 has the fault code at 5000H too
    assert word(drive, 0x3000, 2.0) == 0
    assert words(drive.handle(read(p("P07.27"), 6), 2.0)) == [35, 10, 11, 0, 0, 0]


def test_run_while_faulty_is_refused_and_fault_reset_clears(drive: SimulatedDrive) -> None:
    drive.inject_fault(12, now=0.0)
    assert drive.handle(write(0x2000, 1), 0.5) == bytes.fromhex("86 01")
    assert drive.handle(write(0x2000, 7), 1.0) == write(0x2000, 7)
    assert word(drive, 0x2100, 1.0) == STOPPED
    assert word(drive, 0x2102, 1.0) == 0
    assert word(drive, p("P07.27"), 1.0) == 12  # the history keeps it


def test_communication_timeout_raises_ce() -> None:
    drive = SimulatedDrive(1)
    drive.handle(write(p("P14.04"), 5), 0.0)  # 0.5 s
    assert word(drive, 0x2102, 0.4) == 0
    assert word(drive, 0x2102, 1.0) == 18  # CE


def test_5000h_exists_only_on_the_gd350_family() -> None:
    assert SimulatedDrive(1, "gd20").handle(read(0x5000), 0.0) == bytes.fromhex("83 02")
    assert word(SimulatedDrive(1, "gd350a"), 0x5000, 0.0) == 0


@pytest.mark.parametrize(
    ("model", "code"), [("gd350", 0x01A0), ("gd20", 0x0106), ("gd200a", 0x0107), ("gd10", 0x010D)]
)
def test_identification_per_model(model: str, code: int) -> None:
    drive = SimulatedDrive(1, model)
    assert word(drive, 0x2103, 0.0) == code
    assert word(drive, 0x3016, 0.0) == code
    assert drive.identification == code


# ---------------------------------------------------------------- exceptions


@pytest.mark.parametrize(
    ("request_pdu", "answer"),
    [
        (bytes.fromhex("04 00 00 00 01"), "84 01"),  # function INVT doesn't have
        (bytes.fromhex("08 00 01 00 00"), "88 01"),  # diagnosis other than loop-back
        (read(0x1234), "83 02"),  # nothing there
        (read(0x2000), "83 02"),  # control word: write-only
        (read(0x2100, 17), "83 03"),  # more than 16 words
        (read(0x2100, 0), "83 03"),
        (read(0x8003), "83 02"),  # RAM-only address: write-only
        (read(0x6300), "83 02"),  # P99.00: GD350's manufacturer group
        (read(0x3010, 8), "83 02"),  # runs past 3016H
        (write(0x2100, 1), "86 07"),  # state word: read-only
        (write(p("P07.27"), 0), "86 07"),  # fault history: read-only
        (write(0x2000, 9), "86 04"),  # no such command
        (write(0x2001, 5001), "86 04"),  # above P00.03
        (write(p("P00.01"), 3), "86 04"),
        (write(0x1234, 1), "86 02"),
        (read(0x2100) + b"\x00", "83 06"),  # wrong length: data frame error
        (write(1, 2)[:-1], "86 06"),
        (write_many(0x0004, 1, 2)[:-1], "90 06"),
        (bytes.fromhex("10 00 04 00 02 02 13 88"), "90 03"),  # byte count 2 for 2 words
        (bytes.fromhex("08 00 00 12"), "88 06"),
    ],
)
def test_exceptions_follow_the_invt_meanings(request_pdu: bytes, answer: str) -> None:
    assert SimulatedDrive(1).handle(request_pdu, 0.0) == bytes.fromhex(answer)


@pytest.mark.parametrize(("model", "group"), [("gd350", 99), ("gd10", 29), ("gd300", 29)])
def test_manufacturer_group_can_be_neither_read_nor_written(model: str, group: int) -> None:
    drive = SimulatedDrive(1, model)
    assert drive.handle(read(group << 8), 0.0) == bytes.fromhex("83 02")
    assert drive.handle(write(group << 8, 1), 0.0) == bytes.fromhex("86 02")


def test_locked_parameter_cannot_change_while_running(drive: SimulatedDrive) -> None:
    drive.handle(write(0x2000, 1), 0.0)
    assert drive.handle(write(p("P00.00"), 1), 0.1) == bytes.fromhex("86 08")
    drive.handle(write(0x2000, 6), 0.2)
    assert drive.handle(write(p("P00.00"), 1), 0.3) == write(p("P00.00"), 1)


def test_a_refused_multiple_write_changes_nothing(drive: SimulatedDrive) -> None:
    # P00.11 = 3.0 s is fine, P00.12 = 3700.0 s is not: neither is written.
    assert drive.handle(write_many(p("P00.11"), 30, 37000), 0.0) == bytes.fromhex("90 04")
    assert words(drive.handle(read(p("P00.11"), 2), 0.0)) == [10, 20]


def test_limits_follow_each_other(drive: SimulatedDrive) -> None:
    assert drive.handle(write(p("P00.03"), 4000), 0.0) == bytes.fromhex("86 04")  # < P00.04
    assert drive.handle(write_many(p("P00.04"), 4000), 0.0)[0] == 0x10
    assert drive.handle(write(p("P00.03"), 4000), 0.0)[0] == 0x06
    assert drive.handle(write(0x2001, 4001), 0.0) == bytes.fromhex("86 04")  # > P00.03


# ---------------------------------------------------------------- RAM and EEPROM


def test_ram_only_write_changes_the_value_without_eeprom_wear(drive: SimulatedDrive) -> None:
    eeprom_before = drive.eeprom_writes
    address = ram_address(p("P00.11"))
    assert drive.handle(write(address, 55), 1.0) == write(address, 55)
    assert word(drive, p("P00.11"), 1.0) == 55
    assert drive.ram_writes == 1
    assert drive.eeprom_writes == eeprom_before
    drive.handle(write(p("P00.11"), 60), 1.0)
    assert drive.eeprom_writes == eeprom_before + 1
    assert drive.ram_writes == 1


def test_ram_only_write_with_10h(drive: SimulatedDrive) -> None:
    start = ram_address(p("P00.11"))
    assert drive.handle(write_many(start, 15, 25), 0.0) == write_many(start, 15, 25)[:5]
    assert drive.ram_writes == 2
    assert words(drive.handle(read(p("P00.11"), 2), 0.0)) == [15, 25]


def test_broadcast_write_is_applied(drive: SimulatedDrive) -> None:
    drive.apply_broadcast(write(p("P00.05"), 777), 0.0)
    assert word(drive, p("P00.05"), 0.0) == 777
    drive.apply_broadcast(read(p("P00.05")), 0.0)  # a read can't be broadcast: nothing happens


def test_p14_03_sets_the_response_delay() -> None:
    drive = SimulatedDrive(1)
    assert drive.response_delay_ms == 5
    drive.handle(write(p("P14.03"), 50), 0.0)
    assert drive.response_delay_ms == 50
    assert "P14.03" in drive.written_parameters


def test_constructor_checks_its_inputs() -> None:
    with pytest.raises(ValueError, match=r"outside 1\.\.247"):
        SimulatedDrive(0)
    with pytest.raises(ValueError, match="not an INVT model"):
        SimulatedDrive(1, "generic")
    with pytest.raises(ValueError, match="at most 6 faults"):
        SimulatedDrive(1, fault_history=[1] * 7)
    with pytest.raises(ValueError, match="not a simulated parameter"):
        SimulatedDrive(1, parameters={"P12.01": 1})  # no P12 group


# ---------------------------------------------------------------- pure helpers


def test_ramp_with_zero_time_jumps() -> None:
    ramp = Ramp(0.0)
    ramp.advance(0.001, 30.0, float("inf"), float("inf"))
    assert ramp.frequency_hz == 30.0


def test_request_assembler_cuts_back_to_back_frames_and_drops_garbage() -> None:
    assembler = RequestAssembler(silence_s=0.002)
    first = bytes.fromhex("01 03 00 04 00 02 85 CA")
    second = bytes.fromhex("02 10 00 04 00 02 04 13 88 00 32 F8 63")
    frames = assembler.feed(first + second[:5], 1.0)
    assert [f.data for f in frames] == [first]
    frames = assembler.feed(second[5:], 1.0005)
    assert [f.data for f in frames] == [second]
    # Garbage waits for silence, then comes out as one invalid frame.
    assert assembler.feed(b"\x55\xaa\x03", 2.0) == []
    assert assembler.on_silence(2.001) == []
    (garbage,) = assembler.on_silence(2.003)
    assert not garbage.valid
    # A frame of an unknown function code ends on silence and is valid when its CRC is.
    unknown = bytes.fromhex("01 04 00 00 00 01 31 CA")
    assert assembler.feed(unknown, 3.0) == []
    (frame,) = assembler.on_silence(3.01)
    assert frame.valid
    assert frame.data == unknown


def test_a_gd200a_answers_as_its_manuals_table_says() -> None:
    """Defaults, ranges (exception 04H, INVT's "operation failure") and read-only codes
    (exception 07H) from profile/data/gd200a_parameters.csv."""
    drive = SimulatedDrive(1, "gd200a")
    assert word(drive, p("P05.02"), 0.0) == 4  # S2: forward jogging
    assert word(drive, p("P11.00"), 0.0) == 0x111
    assert word(drive, p("P03.12"), 0.0) == 500  # 50.0 %
    assert drive.handle(write(p("P03.12"), -3000 & 0xFFFF), 0.0)[0] == 0x06  # -300.0 %
    assert drive.handle(write(p("P03.12"), -3001 & 0xFFFF), 0.0) == bytes([0x86, 0x04])
    assert drive.handle(write(p("P00.00"), 0), 0.0) == bytes([0x86, 0x04])  # 1-2 on a GD200A
    assert drive.handle(write(p("P07.11"), 300), 0.0) == bytes([0x86, 0x07])  # temperature ●
    assert drive.handle(read(p("P12.00")), 0.0) == bytes([0x83, 0x02])  # no P12 group


def test_a_new_rated_motor_power_reinitialises_the_motors_data() -> None:
    """GD200A manual, P02: "Resetting the rated motor power (P02.01) will initialize
    P02.02-P02.10"; words after P02.01 in the same 10H write still land."""
    drive = SimulatedDrive(1, "gd200a")
    assert drive.handle(write(p("P02.02"), 4500), 0.0)[0] == 0x06  # 45.00 Hz
    assert drive.handle(write(p("P02.01"), 75), 0.0)[0] == 0x06  # 7.5 kW
    assert word(drive, p("P02.02"), 0.0) == 5000  # back to its default
    assert drive.handle(write_many(p("P02.01"), 110, 4500), 0.0)[0] == 0x10
    assert words(drive.handle(read(p("P02.01"), 2), 0.0)) == [110, 4500]
