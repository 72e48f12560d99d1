"""What an exception code means, in the words of the device that sends it: one table a maker.

A profile names its table (`DriveProfile.exceptions`), and everything that shows a device's
exception asks the profile: MQTT's answers, the console, the poller's log and the field tools.

- `STANDARD_EXCEPTIONS`: the Modbus standard's names (application protocol V1.1b3, section 7;
  07H from the older PI-MBUS-300), for every device that follows it: ABB's drives, meters,
  generic devices, device files.
- `INVT_EXCEPTIONS`: INVT's meanings of 04H-09H, unlike the standard's (the communication
  chapter of INVT's manuals): 06H is "data frame error" (wrong length or CRC), not "server
  busy", so an INVT drive's 06H must never be retried as if the drive were busy.

0AH and 0BH are never sent by a device: the gateway makes them, and both tables name them the
gateway's way. The codes themselves are `gateway.errors.ExceptionCode`; the constants below are
INVT's names for the same members.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Final

from gateway.errors import ExceptionCode

ILLEGAL_COMMAND: Final = ExceptionCode.ILLEGAL_FUNCTION
ILLEGAL_DATA_ADDRESS: Final = ExceptionCode.ILLEGAL_DATA_ADDRESS
ILLEGAL_DATA_VALUE: Final = ExceptionCode.ILLEGAL_DATA_VALUE
OPERATION_FAILURE: Final = ExceptionCode.SERVER_DEVICE_FAILURE
PASSWORD_ERROR: Final = ExceptionCode.ACKNOWLEDGE
DATA_FRAME_ERROR: Final = ExceptionCode.SERVER_DEVICE_BUSY
PARAMETER_READ_ONLY: Final = ExceptionCode.NEGATIVE_ACKNOWLEDGE
NOT_CHANGEABLE_WHILE_RUNNING: Final = ExceptionCode.MEMORY_PARITY_ERROR
PASSWORD_PROTECTION: Final = ExceptionCode.UNASSIGNED_09
GATEWAY_PATH_UNAVAILABLE: Final = ExceptionCode.GATEWAY_PATH_UNAVAILABLE
GATEWAY_TARGET_FAILED: Final = ExceptionCode.GATEWAY_TARGET_FAILED


@dataclass(frozen=True, eq=False)
class ExceptionNames:
    """One maker's words for the exception codes: code → (name, meaning). One instance a
    maker (compared by identity: two drives speak alike when they have the same table)."""

    entries: Mapping[int, tuple[str, str]]

    def name(self, code: int) -> str:
        """ "operation_failure" for an INVT drive's 04H; "exception_<hex>" for a code the
        table doesn't define."""
        entry = self.entries.get(code)
        return entry[0] if entry else f"exception_{code:02x}"

    def describe(self, code: int) -> str:
        """ "04H operation failure: the written value is invalid"."""
        entry = self.entries.get(code)
        if entry is None:
            return f"{code:02X}H unknown exception"
        name, meaning = entry
        return f"{code:02X}H {name.replace('_', ' ')}: {meaning}"


_THE_GATEWAYS: Final[dict[int, tuple[str, str]]] = {
    GATEWAY_PATH_UNAVAILABLE: (
        "gateway_path_unavailable",
        "the gateway has no path to that unit id now (unknown unit, queue full)",
    ),
    GATEWAY_TARGET_FAILED: (
        "gateway_target_failed",
        "the drive gave no valid reply (timeout, offline, port lost)",
    ),
}

STANDARD_EXCEPTIONS: Final = ExceptionNames(
    {
        ExceptionCode.ILLEGAL_FUNCTION: (
            "illegal_function",
            "the device does not take this function code",
        ),
        ExceptionCode.ILLEGAL_DATA_ADDRESS: (
            "illegal_data_address",
            "address, or address + count, not allowed",
        ),
        ExceptionCode.ILLEGAL_DATA_VALUE: (
            "illegal_data_value",
            "a value in the request is not allowed",
        ),
        ExceptionCode.SERVER_DEVICE_FAILURE: (
            "server_device_failure",
            "the device failed while carrying the request out",
        ),
        ExceptionCode.ACKNOWLEDGE: (
            "acknowledge",
            "accepted; the device needs a long time to carry it out",
        ),
        ExceptionCode.SERVER_DEVICE_BUSY: (
            "server_device_busy",
            "the device is busy with a long command; try again later",
        ),
        ExceptionCode.NEGATIVE_ACKNOWLEDGE: (
            "negative_acknowledge",
            "the device cannot carry out the request",
        ),
        ExceptionCode.MEMORY_PARITY_ERROR: (
            "memory_parity_error",
            "the device found a parity error in its memory",
        ),
        **_THE_GATEWAYS,
    }
)

INVT_EXCEPTIONS: Final = ExceptionNames(
    {
        ILLEGAL_COMMAND: ("illegal_command", "function not supported, or the drive is faulty"),
        ILLEGAL_DATA_ADDRESS: (
            "illegal_data_address",
            "address, or address + count, not allowed",
        ),
        ILLEGAL_DATA_VALUE: ("illegal_data_value", "the request's structure holds a wrong value"),
        OPERATION_FAILURE: ("operation_failure", "the written value is invalid"),
        PASSWORD_ERROR: ("password_error", "wrong password"),
        DATA_FRAME_ERROR: ("data_frame_error", "wrong frame length or CRC"),
        PARAMETER_READ_ONLY: ("parameter_read_only", "the parameter is read-only"),
        NOT_CHANGEABLE_WHILE_RUNNING: (
            "not_changeable_while_running",
            "the parameter cannot be changed while running",
        ),
        PASSWORD_PROTECTION: ("password_protection", "the drive is locked by a password"),
        **_THE_GATEWAYS,
    }
)
