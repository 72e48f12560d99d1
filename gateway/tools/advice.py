"""What to check on site when a field tool fails: one checklist per kind of failure.

The wording names the drive's parameters, because that is what the technician can look up on
the keypad: P14.00 address, P14.01 baud, P14.02 data format, P00.01 run command channel,
P00.06 frequency source.
"""

from __future__ import annotations

from gateway.errors import FieldError
from gateway.profile import exception_codes as code
from gateway.profile.exception_codes import INVT_EXCEPTIONS, ExceptionNames

NO_ANSWER = (
    "baud rate and data format: the drive's P14.01 and P14.02 must match --baud and --parity "
    "(factory setting 19200 baud, E81)",
    "the address: P14.00 on the drive's keypad",
    "wiring: A to A (485+), B to B (485-), a common ground; swap A and B if nothing ever answers",
    "termination: 120 ohm at both ends of the line, and nowhere else",
    "the drive is powered and its keypad shows no CE fault",
)
GARBLED = (
    "baud rate and data format: a wrong --baud or --parity arrives as garbage (P14.01, P14.02)",
    "termination: 120 ohm at both ends of the line; long stubs reflect",
    "wiring and shield: twisted pair for A/B, shield earthed at one end only, away from motor "
    "cables",
    "two drives with the same address (P14.00) answering at once",
)
PORT = (
    "the device path: prefer /dev/serial/by-id/... (the name survives re-plugging)",
    "permission: the user must be in the dialout group (then log in again)",
    "nothing else holds the port: a running gateway does; stop it, or go through it with "
    "--via tcp://HOST:PORT",
)
GATEWAY = (
    "the gateway is running and listens there (invt-gateway check-config shows its port)",
    "modbus_tcp.allowed_networks lets this machine in",
)
COMMUNICATION_MODE = (
    "for run commands the drive needs P00.01 = 2 (run command channel: communication)",
    "for a frequency set-point it needs P00.06 = 8 (frequency command: Modbus)",
)

_INVT_EXCEPTION_CHECKS: dict[int, tuple[str, ...]] = {
    code.ILLEGAL_COMMAND: (
        "the drive has no such function, or it is in a fault state: read 2102H",
        *COMMUNICATION_MODE,
    ),
    code.ILLEGAL_DATA_ADDRESS: (
        "the register exists on this model (manufacturer groups P29/P99 are never readable)",
        "INVT reads at most 16 words at once",
    ),
    code.OPERATION_FAILURE: (
        "the value is inside the parameter's range; some ranges depend on another parameter "
        "(P00.04 within P00.05...P00.03)",
    ),
    code.PASSWORD_ERROR: ("the user password (P07.00)",),
    code.DATA_FRAME_ERROR: ("the frame reached the drive damaged: termination, wiring, baud rate",),
    code.PARAMETER_READ_ONLY: ("the parameter is read-only",),
    code.NOT_CHANGEABLE_WHILE_RUNNING: (
        "the parameter can only be changed while the drive is stopped",
    ),
    code.PASSWORD_PROTECTION: ("the drive is locked by a password (P07.00)",),
}
"""What an INVT drive's exception asks to check: INVT's meanings, INVT's parameters."""
_GATEWAY_EXCEPTION_CHECKS: dict[int, tuple[str, ...]] = {
    code.GATEWAY_PATH_UNAVAILABLE: (
        "the gateway's configuration has a drive with this unit id (check-config lists them)",
    ),
    code.GATEWAY_TARGET_FAILED: (
        "the gateway got no answer from the drive: its log says why (offline, timeout, port)",
        *NO_ANSWER[:2],
    ),
}


def exception_error(
    code: int, what: str, exceptions: ExceptionNames = INVT_EXCEPTIONS
) -> FieldError:
    """The error for an exception reply `code` to `what` ("reading P00.11 at address 1"), in
    the words of the device's profile (`exceptions`: INVT's unless `--model` names another)."""
    checks = _GATEWAY_EXCEPTION_CHECKS.get(code)
    if checks is None:
        checks = _INVT_EXCEPTION_CHECKS.get(code, ()) if exceptions is INVT_EXCEPTIONS else ()
    error = FieldError(f"{what}: exception {exceptions.describe(code)}", checks)
    error.exception_code = code
    return error
