"""The traffic monitor names a device's registers from the table the function reads: an
SDM630's input register 0002H is voltage_l2 (04H), its holding register 0002H the demand period
(03H). A drive has one table: 03H and 04H name the same register alike."""

from __future__ import annotations

import struct

from gateway.console.decode import describe
from gateway.profile import get_profile


def read(function: int, start: int, words: list[int]) -> tuple[bytes, bytes]:
    request = struct.pack(">BHH", function, start, len(words))
    reply = struct.pack(f">BB{len(words)}H", function, 2 * len(words), *words)
    return request, reply


def test_a_04h_read_of_a_device_is_named_from_its_input_table() -> None:
    meter = get_profile("sdm630")
    shown = describe(*read(0x04, 0x0002, [0x4366, 0x0000]), meter)
    assert shown.startswith("read voltage_l2")
    assert "demand_period" not in shown


def test_a_03h_read_of_a_device_is_named_from_its_holding_table() -> None:
    meter = get_profile("sdm630")
    assert "demand_period" in describe(*read(0x03, 0x0002, [0x4270, 0x0000]), meter)


def test_a_drive_names_a_register_alike_for_03h_and_04h() -> None:
    drive = get_profile("gd350")
    holding = describe(*read(0x03, 0x2100, [3]), drive)
    assert describe(*read(0x04, 0x2100, [3]), drive) == holding
    assert "state word 1" in holding


def test_a_float32_is_shown_as_the_value_mqtt_publishes_not_its_two_words() -> None:
    meter = get_profile("sdm630")
    words = list(struct.unpack(">2H", struct.pack(">f", 230.5)))  # 4366H 8000H
    shown = describe(*read(0x04, 0x0000, words), meter)
    assert shown.endswith("→ voltage_l1 230.5 V")
    assert "4366H" not in shown


def test_a_point_only_partly_in_the_frame_keeps_its_raw_word() -> None:
    meter = get_profile("sdm630")
    # Input registers 0001H-0003H: the second word of voltage_l1, then voltage_l2 whole.
    words = [0x8000, *struct.unpack(">2H", struct.pack(">f", 229.75))]
    shown = describe(*read(0x04, 0x0001, words), meter)
    assert shown.endswith("→ 0001H 8000H, voltage_l2 229.75 V")


def test_a_write_of_a_float32_names_its_point_and_value() -> None:
    meter = get_profile("sdm630")
    point = next(p for p in meter.typed_points if p.writable and p.kind.value == "f32")
    words = point.encode(15.0)
    request = struct.pack(f">BHHB{len(words)}H", 0x10, point.address, 2, 4, *words)
    shown = describe(request, bytes.fromhex("10") + request[1:5], meter)
    assert shown == f"write {point.name} = 15.0{' ' + point.unit if point.unit else ''} → ok"


def test_a_coil_read_names_the_devices_bool_points() -> None:
    from gateway.profile.device_files import device_profile

    io = device_profile(
        "io",
        "name: io\nsource: test\npoints:\n"
        "  pump_on: {table: coil, address: 0, type: bool}\n"
        "  valve_open: {table: coil, address: 2, type: bool}\n"
        "  door_open: {table: discrete_input, address: 0, type: bool}\n",
        "io.yaml",
    )
    coils = describe(bytes.fromhex("01 0000 0003"), bytes.fromhex("01 01 05"), io)
    assert coils == "read coil 0000H (3 bits) → pump_on on, 0001H off, valve_open on"
    inputs = describe(bytes.fromhex("02 0000 0001"), bytes.fromhex("02 01 00"), io)
    assert inputs == "read discrete input 0000H (1 bits) → door_open off"
