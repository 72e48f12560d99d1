"""Each profile names its own exceptions: INVT's words for INVT's drives, the Modbus standard's
for ABB's drives, generic devices and device files; the gateway's 0AH/0BH alike in both."""

from __future__ import annotations

import pytest

from gateway.errors import ExceptionCode
from gateway.profile import get_profile
from gateway.profile.device_files import shipped_devices

STANDARD_NAMES = {
    0x01: "illegal_function",
    0x02: "illegal_data_address",
    0x03: "illegal_data_value",
    0x04: "server_device_failure",
    0x05: "acknowledge",
    0x06: "server_device_busy",
    0x07: "negative_acknowledge",
    0x08: "memory_parity_error",
    0x0A: "gateway_path_unavailable",
    0x0B: "gateway_target_failed",
}
INVT_NAMES = {
    0x01: "illegal_command",
    0x02: "illegal_data_address",
    0x03: "illegal_data_value",
    0x04: "operation_failure",
    0x05: "password_error",
    0x06: "data_frame_error",
    0x07: "parameter_read_only",
    0x08: "not_changeable_while_running",
    0x09: "password_protection",
    0x0A: "gateway_path_unavailable",
    0x0B: "gateway_target_failed",
}


@pytest.mark.parametrize("model", ["gd350", "gd20", "goodrive300"])
def test_an_invt_drive_speaks_invts_words(model: str) -> None:
    exceptions = get_profile(model).exceptions
    assert {code: exceptions.name(code) for code in INVT_NAMES} == INVT_NAMES
    assert exceptions.describe(0x06) == "06H data frame error: wrong frame length or CRC"


@pytest.mark.parametrize("model", ["acs580", "acs355", "generic"])
def test_other_makers_and_devices_speak_the_standards_words(model: str) -> None:
    exceptions = get_profile(model).exceptions
    assert {code: exceptions.name(code) for code in STANDARD_NAMES} == STANDARD_NAMES
    assert exceptions.name(ExceptionCode.UNASSIGNED_09) == "exception_09"  # none in the standard
    assert "busy" in exceptions.describe(0x06)


def test_every_shipped_device_file_speaks_the_standards_words() -> None:
    for device in shipped_devices():
        assert device.exceptions.name(0x06) == "server_device_busy", device.key


def test_a_sites_corrections_keep_the_makers_words() -> None:
    corrected = get_profile("acs580").with_overrides(faults={1: "OVERCURRENT"})
    assert corrected.exceptions.name(0x06) == "server_device_busy"
    corrected = get_profile("gd350").with_overrides(identification=(1,))
    assert corrected.exceptions.name(0x06) == "data_frame_error"
