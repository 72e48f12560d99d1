"""The INVT drive profile: the facts a user checks against the manual."""

from __future__ import annotations

import pytest

from gateway.profile import (
    COMMUNICATION_REGISTERS,
    FAULTS,
    INVT_EXCEPTIONS,
    PROFILES,
    StateWord2,
    control_command,
    decode_running_values,
    decode_state_word_1,
    decode_state_word_2,
    describe_fault,
    describe_identification,
    encode_state_word_2,
    fault_short_code,
    format_parameter,
    format_register,
    get_profile,
    model_from_identification,
    parameter,
    parameter_decimals,
    parse_parameter,
    parse_register,
    ram_address,
    register_at,
    register_by_name,
    scale_parameter,
    unscale_parameter,
)
from gateway.profile.addressing import parameter_register
from gateway.profile.invt import INVT_PROFILES
from gateway.profile.registers import RUNNING_VALUES

# ---------------------------------------------------------------- parameter addresses


@pytest.mark.parametrize(
    ("name", "address"),
    [
        ("P00.11", 0x000B),
        ("P07.27", 0x071B),
        ("P10.01", 0x0A01),
        ("p14.03", 0x0E03),
        ("P99.99", 0x6363),
        (" P00.00 ", 0x0000),
    ],
)
def test_parameter_names_become_group_and_index_in_decimal(name: str, address: int) -> None:
    assert parse_parameter(name) == address


def test_every_parameter_address_names_itself_back() -> None:
    for group in range(100):
        for index in range(100):
            name = f"P{group:02d}.{index:02d}"
            assert format_parameter(parse_parameter(name)) == name


def test_format_parameter_matches_the_manual_examples() -> None:
    assert format_parameter(0x071B) == "P07.27"
    assert format_parameter(0x000B) == "P00.11"
    assert format_parameter(0x8007) == "P00.07"  # the RAM-only address names the same parameter


@pytest.mark.parametrize("bad", ["P00.100", "P100.00", "00.11", "P0011", "P00-11", ""])
def test_malformed_parameter_names_are_refused(bad: str) -> None:
    with pytest.raises(ValueError, match="not a parameter name"):
        parse_parameter(bad)


def test_group_and_index_beyond_99_are_refused_with_a_reason() -> None:
    with pytest.raises(ValueError, match=r"group 100 is outside 0\.\.99"):
        parameter_register(100, 0)
    with pytest.raises(ValueError, match=r"index 100 is outside 0\.\.99"):
        parameter_register(0, 100)
    with pytest.raises(ValueError, match="not a parameter"):
        format_parameter(0x00FF)  # index 255
    with pytest.raises(ValueError, match="not a parameter"):
        format_parameter(0x6400)  # group 100


def test_ram_only_address_sets_the_top_bit() -> None:
    assert ram_address(0x0007) == 0x8007
    assert ram_address(parse_parameter("P07.27")) == 0x871B
    with pytest.raises(ValueError, match="no RAM-only address"):
        ram_address(0x8007)


@pytest.mark.parametrize(
    ("text", "address"),
    [
        ("2100H", 0x2100),
        ("2100h", 0x2100),
        ("0x2100", 0x2100),
        ("8448", 0x2100),
        ("P00.11", 0x000B),
        ("0", 0),
        ("FFFFH", 0xFFFF),
    ],
)
def test_register_spellings_for_the_cli(text: str, address: int) -> None:
    assert parse_register(text) == address


@pytest.mark.parametrize("bad", ["21G0H", "0x", "70000", "-1", "2100 H", "pump"])
def test_bad_register_spellings_are_refused(bad: str) -> None:
    with pytest.raises(ValueError, match="register"):
        parse_register(bad)


def test_registers_are_written_the_way_the_manual_writes_them() -> None:
    assert format_register(0x2100) == "2100H"
    assert format_register(0x0B) == "000BH"


# ---------------------------------------------------------------- communication registers


def test_register_map_by_name_and_by_address() -> None:
    assert register_by_name("control_word").address == 0x2000
    assert register_by_name("frequency_setpoint").address == 0x2001
    assert register_by_name("state_word_1").address == 0x2100
    assert register_by_name("fault_code").address == 0x2102
    assert register_by_name("identification").address == 0x2103
    assert register_by_name("running_frequency").address == 0x3000
    assert register_by_name("torque_reference").address == 0x3015
    bus = register_at(0x3002)
    assert bus is not None
    assert (bus.name, bus.decimals, bus.unit) == ("bus_voltage", 1, "V")
    assert register_at(0x000B) is None  # a parameter, not a communication register
    with pytest.raises(ValueError, match="unknown register 'speed'"):
        register_by_name("speed")


def test_register_map_covers_the_protocol_table_without_duplicates() -> None:
    addresses = [register.address for register in COMMUNICATION_REGISTERS]
    names = [register.name for register in COMMUNICATION_REGISTERS]
    assert len(set(addresses)) == len(addresses)
    assert len(set(names)) == len(names)
    for block in (range(0x2000, 0x200F), range(0x2100, 0x2104), range(0x3000, 0x3016)):
        assert set(block) <= set(addresses)


def test_write_only_read_only_and_signed_registers() -> None:
    control = register_by_name("control_word")
    assert control.writable
    assert not control.readable
    state = register_by_name("state_word_1")
    assert state.readable
    assert not state.writable
    assert register_by_name("frequency_setpoint").writable
    assert register_by_name("output_torque").signed
    assert register_by_name("output_power").signed
    assert not register_by_name("output_current").signed


def test_values_are_scaled_by_their_decimals() -> None:
    frequency = register_by_name("running_frequency")
    assert frequency.decode(0x1394) == pytest.approx(50.12)
    assert frequency.encode(50.12) == 0x1394
    torque = register_by_name("output_torque")
    assert torque.decode(0xFF9C) == pytest.approx(-10.0)
    assert torque.encode(-10.0) == 0xFF9C
    assert register_by_name("rotation_speed").decode(1455) == 1455
    with pytest.raises(ValueError, match="does not fit"):
        frequency.encode(700.0)


def test_running_values_become_telemetry_keys_with_units() -> None:
    words = [5000, 5000, 5400, 380, 123, 1455, 0xFF9C, 655, 0, 0, 0b101, 0]
    values = decode_running_values(0x3000, words)
    assert values == {
        "output_frequency_hz": 50.0,
        "set_frequency_hz": 50.0,
        "bus_voltage_v": 540.0,
        "output_voltage_v": 380,
        "output_current_a": 12.3,
        "rotation_speed_rpm": 1455,
        "output_power_pct": -10.0,
        "output_torque_pct": 65.5,
        "pid_reference_pct": 0.0,
        "pid_feedback_pct": 0.0,
        "input_terminals": 5,
        "output_terminals": 0,
    }
    assert [value.register.address for value in RUNNING_VALUES] == list(range(0x3000, 0x300C))


def test_a_model_can_override_the_bus_voltage_scale() -> None:
    values = decode_running_values(0x3002, [540], {"bus_voltage": 0})
    assert values == {"bus_voltage_v": 540}


# ---------------------------------------------------------------- state and control words


@pytest.mark.parametrize(
    ("value", "state"),
    [
        (1, "running_forward"),
        (2, "running_reverse"),
        (3, "stopped"),
        (4, "fault"),
        (5, "power_off"),
        (6, "pre_exciting"),
        (0, "unknown_0"),
        (9, "unknown_9"),
    ],
)
def test_state_word_1(value: int, state: str) -> None:
    assert decode_state_word_1(value) == state


def test_state_word_2_bits() -> None:
    # bit 0 ready, bits 2-1 = 01 (motor 2), bit 4 overload pre-alarm, bits 6-5 = 10 communication
    word = 0b1_0_1_0_01_1
    decoded = decode_state_word_2(word, True)
    assert decoded == StateWord2(
        ready=True,
        motor=2,
        synchronous_motor=False,
        overload_pre_alarm=True,
        command_source="communication",
    )
    assert decode_state_word_2(0b0100000, True).command_source == "terminal"
    assert decode_state_word_2(0b1100000, True).command_source == "unknown_3"
    assert decode_state_word_2(0b0001000, True).synchronous_motor
    # Where bit 0 = 0 means ready (a model with the other polarity):
    assert decode_state_word_2(0, ready_bit_set_means_ready=False).ready
    # A series not known: bit 0 is left undecided, the rest decoded.
    unknown = decode_state_word_2(word, None)
    assert (unknown.ready, unknown.command_source) == (None, "communication")
    assert encode_state_word_2(decoded, True) == word


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("run_forward", 1),
        ("run_reverse", 2),
        ("jog_forward", 3),
        ("jog_reverse", 4),
        ("stop", 5),
        ("coast_stop", 6),
        ("fault_reset", 7),
        ("jog_stop", 8),
        ("Fault-Reset", 7),
    ],
)
def test_control_word_commands(name: str, value: int) -> None:
    assert control_command(name) == value


def test_unknown_command_lists_the_valid_ones() -> None:
    with pytest.raises(ValueError, match=r"run_forward.*jog_stop"):
        control_command("start")


# ---------------------------------------------------------------- faults and exceptions


def test_fault_descriptions() -> None:
    assert describe_fault(35) == "STo: maladjustment"
    assert describe_fault(18) == "CE: RS-485 communication fault"
    assert describe_fault(10) == "UV: bus undervoltage"
    assert describe_fault(0) == "none"
    assert describe_fault(40) == "STO"  # GD350: the manual gives only the short code
    assert describe_fault(69) == "S-Err"
    assert describe_fault(99) == "unknown fault 99"
    assert fault_short_code(35) == "STo"
    assert fault_short_code(123) == "123"


def test_fault_table_is_complete_from_0_to_69() -> None:
    assert set(FAULTS) == set(range(70))
    assert FAULTS[45][0] == "P-E1"
    assert FAULTS[54][0] == "P-E10"
    assert FAULTS[56][0] == "ENCU"


def test_exception_codes_carry_invt_meanings() -> None:
    assert INVT_EXCEPTIONS.name(0x04) == "operation_failure"
    assert INVT_EXCEPTIONS.name(0x06) == "data_frame_error"  # not "server busy"
    assert INVT_EXCEPTIONS.name(0x07) == "parameter_read_only"
    assert INVT_EXCEPTIONS.name(0x0A) == "gateway_path_unavailable"
    assert INVT_EXCEPTIONS.name(0x0B) == "gateway_target_failed"
    assert INVT_EXCEPTIONS.name(0x42) == "exception_42"
    assert INVT_EXCEPTIONS.describe(0x06).startswith("06H data frame error")
    assert "busy" not in INVT_EXCEPTIONS.describe(0x06)
    assert INVT_EXCEPTIONS.describe(0x04) == "04H operation failure: the written value is invalid"
    assert all(INVT_EXCEPTIONS.name(code) != f"exception_{code:02x}" for code in range(0x01, 0x0C))


# ---------------------------------------------------------------- models


@pytest.mark.parametrize(
    ("code", "model"),
    [
        (0x0106, "GD20"),
        (0x0107, "GD200A"),
        (0x010C, "GD200A"),
        (0x0108, "GD35"),
        (0x0109, "GD35-H1"),
        (0x010A, "GD300 or GD300-LIFT"),  # the Goodrive300-LIFT manual: "GD300-----0x010a"
        (0x010B, "GD100"),
        (0x010D, "GD10"),
        (0x01A0, "GD350"),
        (0x01A1, "GD350-UL"),
        (0x01A2, "GD350A"),
    ],
)
def test_identification_codes(code: int, model: str) -> None:
    assert model_from_identification(code) == model


def test_unknown_identification_is_shown_in_hex() -> None:
    assert model_from_identification(0x0199) is None
    assert describe_identification(0x0199) == "unknown series (0199H)"


def test_every_model_has_a_profile() -> None:
    assert set(PROFILES) == {
        "gd20",
        "gd200a",
        "gd300",
        "gd350",
        "gd350a",
        "gd350ul",
        "gd10",
        "gd35",
        "gd100",
        "gd30",
        "ipe300",
        "gd300l",
        "acs355",
        "acs580",
        "generic",
        "sdm630",  # the shipped device files: devices of typed points
        "analog_input_4_20ma",
    }
    for key, profile in PROFILES.items():
        assert profile.key == key
        for code in profile.identification:  # INVT's 2103H codes (an ABB drive answers none)
            assert profile.display_name in str(model_from_identification(code)).split(" or ")


def test_get_profile_is_forgiving_about_spelling_and_lists_the_valid_names() -> None:
    assert get_profile("GD350").key == "gd350"
    assert get_profile("gd350-ul").key == "gd350ul"
    with pytest.raises(ValueError, match="valid profiles are gd20, gd200a"):
        get_profile("gd999")


def test_invt_profiles_share_the_manual_facts() -> None:
    for profile in INVT_PROFILES.values():
        assert profile.manufacturer == "INVT"
        assert profile.max_words == 16
        assert profile.fault_register == 0x2102
        assert profile.ram_writes_supported
        state, running = profile.poll_groups
        assert (state.start, state.count, state.interval_s) == (0x2100, 3, 0.5)
        assert (running.start, running.count, running.interval_s) == (0x3000, 12, 2.0)


def test_model_differences_are_data() -> None:
    assert INVT_PROFILES["gd350"].fault_registers == (0x2102, 0x5000)
    assert INVT_PROFILES["gd350a"].fault_registers == (0x2102, 0x5000)
    assert INVT_PROFILES["gd20"].fault_registers == (0x2102,)
    assert get_profile("gd200a").identification == (0x0107, 0x010C)
    assert INVT_PROFILES["gd350"].manufacturer_group == 99
    assert INVT_PROFILES["gd10"].manufacturer_group == 29
    assert INVT_PROFILES["gd300"].manufacturer_group == 29
    assert INVT_PROFILES["gd350"].virtual_input_bits == 10
    assert INVT_PROFILES["gd20"].virtual_input_bits == 9


def test_generic_device_is_never_split_and_has_no_invt_knowledge() -> None:
    generic = get_profile("generic")
    assert generic.manufacturer == ""
    assert generic.max_words >= 125
    assert not generic.split_by_default
    assert generic.current_fault({0x2102: 18}) is None
    assert generic.telemetry({0x2100: 3}) == {"register_2100h": 3}
    assert generic.point(0x2100) is None
    assert generic.commands == ()
    assert generic.poll_groups == ()
    assert not generic.ram_writes_supported


# ---------------------------------------------------------------- parameter scaling


@pytest.mark.parametrize(
    ("name", "decimals"),
    [
        ("P00.03", 2),
        ("P00.04", 2),
        ("P00.05", 2),
        ("P00.11", 1),
        ("P00.12", 1),
        ("P01.20", 1),
        ("P08.06", 2),
        ("P14.03", 0),
        ("P14.04", 1),
    ],
)
def test_known_parameter_decimals(name: str, decimals: int) -> None:
    assert parameter_decimals(name) == decimals


def test_parameters_scale_to_register_values() -> None:
    assert scale_parameter("P00.11", 10.0) == 100
    assert scale_parameter("P00.03", 100.0) == 0x2710
    assert scale_parameter("P00.04", 50.0) == 0x1388
    assert scale_parameter("P01.20", 5.0) == 0x0032
    assert scale_parameter("P14.03", 5) == 5
    assert unscale_parameter("P00.03", 5000) == pytest.approx(50.0)
    assert unscale_parameter("P14.03", 5) == 5
    with pytest.raises(ValueError, match="does not fit"):
        scale_parameter("P00.03", 1000.0)


def test_parameter_without_known_decimals_asks_for_a_raw_value() -> None:
    with pytest.raises(ValueError, match=r"P05\.01 is not in the profile.s parameter table"):
        scale_parameter("P05.01", 1.0)


def test_fault_history_parameters_are_read_only() -> None:
    for name in ("P07.27", "P07.28", "P07.29", "P07.30", "P07.31", "P07.32"):
        assert parameter(name).read_only
    assert not parameter("P00.11").read_only
    assert parameter("P00.03").address == 0x0003
