"""Device files: the shipped ones load and say where their map comes from; a wrong one is
refused with its file and key path; reads are planned into as few whole requests as allowed."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from gateway.errors import DeviceFileError
from gateway.profile import get_profile
from gateway.profile.device_files import device_profile
from gateway.profile.point_types import Table, word_key
from gateway.profile.points_device import DeviceProfile

HEADER = "name: test meter\nsource: a test\n"
TEST_METER = Path(__file__).parents[2] / "fixtures" / "devices" / "test_meter.yaml"


def profile_of(text: str) -> DeviceProfile:
    return device_profile("meter", HEADER + text, "meter.yaml")


@pytest.mark.parametrize("model", ["sdm630", "analog_input_4_20ma"])
def test_shipped_device_files_are_models_with_their_source(model: str) -> None:
    profile = get_profile(model)
    assert isinstance(profile, DeviceProfile)
    assert "registers" in profile.source or "register" in profile.source
    assert profile.poll_groups
    assert profile.telemetry_keys == {p.name for p in profile.typed_points}


def test_the_sdm630_reads_its_floats_in_two_requests_of_input_registers() -> None:
    profile = get_profile("sdm630")
    inputs = [g for g in profile.poll_groups if g.table is Table.INPUT]
    assert [(g.start, g.count) for g in inputs] == [(0, 54), (62, 14)]
    assert all(g.count <= profile.max_words for g in profile.poll_groups)
    # 30001 is phase 1's volts: address 0, an f32 (43 66 80 00 = 230.5).
    assert profile.telemetry({0x10000: 0x4366, 0x10001: 0x8000}) == {"voltage_l1": 230.5}


def test_a_site_file_is_named_by_its_path(tmp_path: Path) -> None:
    path = tmp_path / "mymeter.yaml"
    path.write_text(HEADER + "points:\n  level: {table: input, address: 0x10, type: s16}\n")
    profile = get_profile(f"file:{path}")
    assert profile.display_name == "test meter"
    assert profile.telemetry({0x10010: 0xFFFF}) == {"level": -1}
    with pytest.raises(ValueError, match=r"nothere\.yaml"):
        get_profile(f"file:{tmp_path / 'nothere.yaml'}")


@pytest.mark.parametrize(
    ("points", "message"),
    [
        (
            "  a: {address: 0, type: f32}\n  b: {address: 1}\n",
            "meter.yaml: points.b: overlaps points.a at holding register 0001H",
        ),
        ("  a: {address: 0, type: f33}\n", "meter.yaml: points.a.type: Input should be"),
        ("  a: {address: 0x1FFFF}\n", "meter.yaml: points.a.address: Value error"),
        ("  a: {address: 0, type: bit, bit: 16}\n", "meter.yaml: points.a.bit: a bit point"),
        ("  a: {table: coil, address: 0, type: u32}\n", "meter.yaml: points.a.type: a coil"),
        (
            "  a: {address: 0, type: bit, bit: 1, writable: true}\n",
            "points.a.writable: a bit can't",
        ),
        (
            "  a: {table: input, address: 0, writable: true}\n",
            "points.a.writable: input registers and discrete inputs are read-only",
        ),
        ("  a: {address: 0, type: string}\n", "points.a.registers: a string needs its length"),
        ("  a: {address: 0, type: enum}\n", "points.a.values: an enum needs values"),
        ("  a: {address: 0, typo: 1}\n", "meter.yaml: points.a.typo: Extra inputs"),
        ("  Bad-Name: {address: 0}\n", "meter.yaml: points.Bad-Name"),
        (
            "  a: {address: 0, type: bit, bit: 1}\n  b: {address: 0, type: bit, bit: 1}\n",
            "points.b: bit 1 of 0000H is another point's too",
        ),
    ],
)
def test_a_wrong_point_is_named_with_its_key_path(points: str, message: str) -> None:
    with pytest.raises(DeviceFileError, match=re.escape(message)):
        profile_of("points:\n" + points)


def test_bits_of_one_register_may_sit_beside_its_word() -> None:
    profile = profile_of(
        "points:\n  status: {address: 0}\n  running: {address: 0, type: bit, bit: 0}\n"
        "  tripped: {address: 0, type: bit, bit: 3}\n"
    )
    assert profile.telemetry({0: 0b1001}) == {"status": 9, "running": True, "tripped": True}


def test_reads_merge_across_allowed_gaps_and_never_split_a_value() -> None:
    profile = profile_of(
        "max_registers: 6\nmax_gap: 2\npoints:\n"
        "  a: {address: 0, type: f32}\n"  # 0-1
        "  b: {address: 3, type: f32}\n"  # 3-4: a gap of 1, read across
        "  c: {address: 5, type: f32}\n"  # 5-6: would make 7 > 6 registers: a new request
        "  d: {address: 20}\n"  # a gap of 13 > 2: a new request
        "  e: {table: coil, address: 0, type: bool}\n"
        "  f: {table: coil, address: 9, type: bool}\n"
        "  slow: {address: 7, interval_ms: 10000}\n"
    )
    reads = {(g.table.value, g.start, g.count, g.interval_s) for g in profile.poll_groups}
    assert reads == {
        ("holding", 0, 5, 1.0),
        ("holding", 5, 2, 1.0),
        ("holding", 20, 1, 1.0),
        ("coil", 0, 1, 1.0),
        ("coil", 9, 1, 1.0),
        ("holding", 7, 1, 10.0),
    }


def test_a_point_longer_than_one_request_allows_is_refused() -> None:
    with pytest.raises(DeviceFileError, match=r"points\.name: 10 registers, more than"):
        profile_of("max_registers: 8\npoints:\n  name: {type: string, address: 0, registers: 10}\n")


def test_a_point_is_named_in_its_own_table() -> None:
    profile = get_profile("sdm630")
    named = profile.point(word_key(Table.INPUT, 3))  # phase 2's volts, second register
    assert named is not None
    assert named.label == "voltage_l2"
    holding = profile.point(3)  # holding register 3: the demand period's second register
    assert holding is not None
    assert holding.label == "demand_period"
    assert get_profile("analog_input_4_20ma").telemetry({0x10000: 65535}) == {"channel_1": 20.0}


def test_limits_only_on_numbers_and_low_below_high() -> None:
    with pytest.raises(DeviceFileError, match=r"points\.a\.low: must be below high \(5\)"):
        profile_of("points:\n  a: {address: 0, high: 5, low: 5}\n")
    with pytest.raises(DeviceFileError, match=r"points\.a\.high: only a number has limits"):
        profile_of("points:\n  a: {address: 0, type: string, registers: 2, high: 5}\n")


def test_the_field_tools_get_single_holding_registers_only() -> None:
    profile = get_profile(f"file:{TEST_METER}")
    temperature = profile.resolve("temperature")
    assert (temperature.address, temperature.show(0xFF83, profile)) == (30, "-12.5 °C")
    with pytest.raises(ValueError, match="flow is a f32 in the input table"):
        profile.resolve("flow")
    with pytest.raises(ValueError, match="setpoint is a f32 in the holding table"):
        profile.resolve("setpoint")
