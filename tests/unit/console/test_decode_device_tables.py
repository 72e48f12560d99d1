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
