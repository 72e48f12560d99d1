"""What an exception code means when an INVT drive (or this gateway) sends it.

INVT gives 04H-09H meanings of its own, unlike the Modbus standard: 06H is "data frame error"
(wrong length or CRC), not "server busy", so a 06H must never be retried as if the drive were busy.
0AH and 0BH are never sent by a drive: the gateway makes them. The codes themselves are
`gateway.errors.ExceptionCode`; the names below are INVT's for the same members.
"""

from __future__ import annotations

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

EXCEPTIONS: Final[dict[int, tuple[str, str]]] = {
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
    GATEWAY_PATH_UNAVAILABLE: (
        "gateway_path_unavailable",
        "the gateway has no path to that unit id now (unknown unit, queue full)",
    ),
    GATEWAY_TARGET_FAILED: (
        "gateway_target_failed",
        "the drive gave no valid reply (timeout, offline, port lost)",
    ),
}


def exception_name(code: int) -> str:
    """ "operation_failure" for 04H; "exception_<hex>" for a code INVT doesn't define."""
    entry = EXCEPTIONS.get(code)
    return entry[0] if entry else f"exception_{code:02x}"


def describe_exception(code: int) -> str:
    """ "04H operation failure: the written value is invalid"."""
    entry = EXCEPTIONS.get(code)
    if entry is None:
        return f"{code:02X}H unknown exception"
    name, meaning = entry
    return f"{code:02X}H {name.replace('_', ' ')}: {meaning}"
