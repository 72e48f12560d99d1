"""Is a request PDU well formed for its function code? When it is not, the reason, not just False.

The limits are the Modbus application protocol's (V1.1b3, section 6; its state diagrams answer
each violation with exception 03H): a block read asks for 1..2000 bits (01H 02H) or 1..125
registers (03H 04H); a block write carries 1..1968 bits (0FH) in ceil(n/8) bytes or 1..123
registers (10H) in 2n bytes; 17H reads 1..125 and writes 1..121; 05H writes FF00H (on) or 0000H
(off) and nothing else; 14H asks in 7-byte sub-requests, 7..245 bytes of them; 15H sends 9..251.
What depends on the device (which addresses exist, which 08H sub-functions or objects it has) is
the device's to refuse; this layer only checks the shape any device would refuse.

A reason maps to the exception code a front door would answer (`Malformed.exception_code`): 01H
for a byte that is not a function code at all, 03H for everything else (the spec's "the implied
length is incorrect" is 03H too).
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum
from typing import Final

from gateway.errors import ExceptionCode

MAX_PDU: Final = 253
"""The serial line's 256-byte frame less address and CRC; Modbus-TCP keeps the same limit."""
MAX_READ_BITS: Final = 2000
MAX_WRITE_BITS: Final = 1968
MAX_READ_REGISTERS: Final = 125
MAX_WRITE_REGISTERS: Final = 123
MAX_READ_WRITE_WRITES: Final = 121
"""17H writes at most 121 registers (it reads up to 125 in the same PDU)."""
COIL_ON: Final = 0xFF00
COIL_OFF: Final = 0x0000
MEI_DEVICE_IDENTIFICATION: Final = 0x0E
READ_DEVICE_ID_CODES: Final = range(1, 5)
"""01 basic, 02 regular, 03 extended (stream access), 04 one specific object."""
FILE_SUB_REQUEST: Final = 7
"""14H: reference type, file number, record number, record length: 7 bytes each."""

_TWO_WORDS: Final = struct.Struct(">HH")


class Reason(StrEnum):
    """Why a request is malformed; the values are fit for a metric label."""

    FUNCTION_CODE = "function_code"
    """00H, or 80H and above: not a function code (80H+ is an exception reply's)."""
    LENGTH = "length"
    """The PDU is shorter or longer than its function's shape."""
    QUANTITY = "quantity"
    """The count of bits or registers is outside the function's limits."""
    BYTE_COUNT = "byte_count"
    """The byte count disagrees with the quantity, or with the bytes that follow it."""
    VALUE = "value"
    """A field holds a value the function doesn't define (05H's FF00H/0000H, 2BH/0EH's code)."""

    @property
    def exception_code(self) -> ExceptionCode:
        if self is Reason.FUNCTION_CODE:
            return ExceptionCode.ILLEGAL_FUNCTION
        return ExceptionCode.ILLEGAL_DATA_VALUE


@dataclass(frozen=True, slots=True)
class Malformed:
    reason: Reason
    detail: str
    """For a log line: "quantity 126 outside 1..125"."""

    @property
    def exception_code(self) -> ExceptionCode:
        return self.reason.exception_code


RequestCheck = Callable[[bytes], Malformed | None]
"""None for a well-formed request PDU (function code first), else why not."""


def _length(pdu: bytes, low: int, high: int = MAX_PDU) -> Malformed | None:
    if low <= len(pdu) <= high:
        return None
    expected = str(low) if low == high else f"{low}..{high}"
    return Malformed(Reason.LENGTH, f"{pdu[0]:02X}H request of {len(pdu)} bytes, not {expected}")


def _quantity(quantity: int, high: int, what: str = "quantity") -> Malformed | None:
    if 1 <= quantity <= high:
        return None
    return Malformed(Reason.QUANTITY, f"{what} {quantity} outside 1..{high}")


def _byte_count(count: int, expected: int, pdu: bytes, offset: int) -> Malformed | None:
    if count != expected:
        return Malformed(Reason.BYTE_COUNT, f"byte count {count}, expected {expected}")
    if len(pdu) != offset + count:
        return Malformed(
            Reason.BYTE_COUNT, f"byte count {count} but {len(pdu) - offset} bytes follow it"
        )
    return None


def exactly(length: int) -> RequestCheck:
    """A request of one fixed shape: 06H (5 bytes), 16H (7), 18H (3), 07H 0BH 0CH 11H (1)."""

    def check(pdu: bytes) -> Malformed | None:
        return _length(pdu, length, length)

    return check


def block_read(max_quantity: int) -> RequestCheck:
    """01H-04H: start address, quantity 1..`max_quantity`."""

    def check(pdu: bytes) -> Malformed | None:
        if problem := _length(pdu, 5, 5):
            return problem
        _, quantity = _TWO_WORDS.unpack_from(pdu, 1)
        return _quantity(quantity, max_quantity)

    return check


def bits(quantity: int) -> int:
    """Bytes that carry `quantity` bits, eight to a byte."""
    return (quantity + 7) // 8


def words(quantity: int) -> int:
    return 2 * quantity


def block_write(max_quantity: int, bytes_for: Callable[[int], int]) -> RequestCheck:
    """0FH and 10H: start, quantity 1..`max_quantity`, byte count = `bytes_for(quantity)`, data."""

    def check(pdu: bytes) -> Malformed | None:
        if problem := _length(pdu, 6):
            return problem
        _, quantity = _TWO_WORDS.unpack_from(pdu, 1)
        return _quantity(quantity, max_quantity) or _byte_count(pdu[5], bytes_for(quantity), pdu, 6)

    return check


def write_single_coil(pdu: bytes) -> Malformed | None:
    """05H: the output value is FF00H (on) or 0000H (off), nothing else."""
    if problem := _length(pdu, 5, 5):
        return problem
    value = int.from_bytes(pdu[3:5], "big")
    if value in (COIL_ON, COIL_OFF):
        return None
    return Malformed(Reason.VALUE, f"coil value {value:04X}H, not FF00H or 0000H")


def diagnostics(pdu: bytes) -> Malformed | None:
    """08H: a sub-function and its data (which sub-functions exist is the device's business)."""
    return _length(pdu, 3)


def read_write_registers(pdu: bytes) -> Malformed | None:
    """17H: read start and quantity 1..125, write start and quantity 1..121, byte count 2n, data."""
    if problem := _length(pdu, 10):
        return problem
    _, reads, _, writes = struct.unpack_from(">HHHH", pdu, 1)
    return (
        _quantity(reads, MAX_READ_REGISTERS, "read quantity")
        or _quantity(writes, MAX_READ_WRITE_WRITES, "write quantity")
        or _byte_count(pdu[9], words(writes), pdu, 10)
    )


def file_records(low: int, high: int, step: int = 1) -> RequestCheck:
    """14H and 15H: a byte count `low`..`high` (a multiple of `step`), then that many bytes."""

    def check(pdu: bytes) -> Malformed | None:
        if problem := _length(pdu, 2):
            return problem
        count = pdu[1]
        if not low <= count <= high or count % step:
            steps = f" in steps of {step}" if step > 1 else ""
            return Malformed(Reason.BYTE_COUNT, f"byte count {count} outside {low}..{high}{steps}")
        return _byte_count(count, count, pdu, 2)

    return check


def encapsulated_interface(pdu: bytes) -> Malformed | None:
    """2BH: a MEI type; for 0EH (device identification) a read code 01..04 and an object id."""
    if problem := _length(pdu, 2):
        return problem
    if pdu[1] != MEI_DEVICE_IDENTIFICATION:
        return None  # 0DH (CANopen) and the reserved types: the device's to judge
    if problem := _length(pdu, 4, 4):
        return problem
    if pdu[2] not in READ_DEVICE_ID_CODES:
        return Malformed(Reason.VALUE, f"read device id code {pdu[2]:02X}H, not 01H..04H")
    return None


def any_function(pdu: bytes) -> Malformed | None:
    """A function code this table doesn't know (a vendor's): only the PDU's size is checked."""
    return _length(pdu, 1)


def function_code(pdu: bytes) -> Malformed | None:
    """What every request needs before its function's own check: a function code, 01H..7FH."""
    if not pdu:
        return Malformed(Reason.LENGTH, "an empty PDU has no function code")
    if pdu[0] == 0 or pdu[0] & 0x80:
        return Malformed(Reason.FUNCTION_CODE, f"{pdu[0]:02X}H is not a function code")
    return None
