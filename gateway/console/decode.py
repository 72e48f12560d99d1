"""A transaction in INVT's words, for the traffic monitor.

    read 2100H state word 1 → 0003H stopped
    write P00.11 = 10.0 s
    write 2000H control word = 1 (run_forward) → ok
    loop-back 08H (probe) → echoed

For a drive whose profile is not INVT (`generic`), registers keep their addresses and raw words.
The status words are put in words by the drive's own series (`gateway.profile.words`), so the
monitor says what the drive page and MQTT say: 0041H is "ready" on a GD350, "not ready" on a
GD300-LIFT.
"""

from __future__ import annotations

import struct

from gateway.modbus.functions import (
    DIAGNOSTICS,
    READ_HOLDING_REGISTERS,
    READ_INPUT_REGISTERS,
    WRITE_MULTIPLE_REGISTERS,
    WRITE_SINGLE_REGISTER,
)
from gateway.profile import DriveProfile, exception_name, format_register, is_ram_address
from gateway.tools.points import Point, resolve

MAX_VALUES_SHOWN = 4
"""A 12-word poll names its first values and says how many more: a line stays one line."""


def describe_request(pdu: bytes, profile: DriveProfile | None) -> str:
    """What the request asks, without its answer (None: a drive the gateway has no profile of)."""
    if not pdu:
        return "empty request"
    function = pdu[0]
    if function in (READ_HOLDING_REGISTERS, READ_INPUT_REGISTERS) and len(pdu) == 5:
        start, count = struct.unpack(">HH", pdu[1:5])
        return f"read {_span(start, count, _invt(profile))}"
    if function == WRITE_SINGLE_REGISTER and len(pdu) == 5:
        address, value = struct.unpack(">HH", pdu[1:5])
        return f"write {_assignment(address, value, profile)}"
    if function == WRITE_MULTIPLE_REGISTERS and len(pdu) >= 6:
        start, count = struct.unpack(">HH", pdu[1:5])
        words = _words(pdu[6:])
        shown = ", ".join(
            _assignment(start + i, w, profile) for i, w in enumerate(words[:MAX_VALUES_SHOWN])
        )
        more = f", +{count - MAX_VALUES_SHOWN} more" if count > MAX_VALUES_SHOWN else ""
        return f"write {shown}{more}"
    if function == DIAGNOSTICS:
        return "loop-back 08H"
    return f"function {function:02X}H"


def describe(pdu: bytes, reply: bytes | None, profile: DriveProfile | None) -> str:
    """The request and, when the drive answered, what the answer says."""
    request = describe_request(pdu, profile)
    if reply is None:
        return request
    if reply and reply[0] & 0x80:
        code = reply[1] if len(reply) > 1 else 0
        return f"{request} → exception {code:02X}H {exception_name(code)}"
    if not pdu:
        return request
    function = pdu[0]
    if function in (READ_HOLDING_REGISTERS, READ_INPUT_REGISTERS) and len(pdu) == 5:
        (start,) = struct.unpack(">H", pdu[1:3])
        words = _words(reply[2:])
        shown = ", ".join(
            _value(start + i, w, profile, named=len(words) > 1)
            for i, w in enumerate(words[:MAX_VALUES_SHOWN])
        )
        more = f", +{len(words) - MAX_VALUES_SHOWN} more" if len(words) > MAX_VALUES_SHOWN else ""
        return f"{request} → {shown}{more}"
    if function == DIAGNOSTICS:
        return f"{request} → echoed" if reply == pdu else f"{request} → {reply.hex(' ')}"
    return f"{request} → ok"


def _span(start: int, count: int, invt: bool) -> str:
    first = _name(start, invt)
    if count == 1:
        return first
    last = start + count - 1
    last_name = _point(last).label if invt and first.startswith("P") else format_register(last)
    return f"{first} … {last_name} ({count} words)"


def _name(address: int, invt: bool) -> str:
    """ "2100H state word 1", "P00.11", "P00.11 (RAM)", "0005H"."""
    if not invt:
        return format_register(address)
    point = _point(address)
    if point.label.startswith("P"):
        return f"{point.label} (RAM)" if is_ram_address(address) else point.label
    named = point.description.split(":", 1)[0] if point.unit or point.description else ""
    if not named or point.description.startswith("not in the profile"):
        return point.label
    return f"{point.label} {named}"


def _assignment(address: int, value: int, profile: DriveProfile | None) -> str:
    if not _invt(profile):
        return f"{format_register(address)} = {value:04X}H"
    return f"{_name(address, True)} = {_point(address).show(value, profile)}"


def _value(address: int, value: int, profile: DriveProfile | None, *, named: bool) -> str:
    if not _invt(profile):
        return f"{value:04X}H"
    point = _point(address)
    shown = point.show(value, profile)
    if point.meaning.value == "state_word_1":
        shown = f"{value:04X}H {shown.split('(', 1)[1].rstrip(')')}"
    if not named:
        return shown
    return f"{point.label if point.label.startswith('P') else format_register(address)} {shown}"


def _invt(profile: DriveProfile | None) -> bool:
    return profile is not None and profile.is_invt


def _point(address: int) -> Point:
    return resolve(format_register(address))


def _words(data: bytes) -> list[int]:
    return list(struct.unpack(f">{len(data) // 2}H", data[: len(data) // 2 * 2]))
