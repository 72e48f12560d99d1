"""A transaction in the drive's own words (its profile's), for the traffic monitor.

    read 2100H state word 1 → 0003H stopped
    write P00.11 = 10.0 s
    write 2000H control word = 1 (run_forward) → ok
    loop-back 08H (probe) → echoed

A register the drive's profile doesn't name (every register of a `generic` device) keeps its
address and raw word. A device file's points are shown as MQTT publishes them (a float32 as
230.5 V, not its two words), decoded by the device's profile from the words the frame carries
(`device_values`), a coil's or discrete input's as on or off; a point only partly in the frame
keeps its raw words.

The status words are put in words by the drive's own profile, so the monitor says what the drive
page and MQTT say: 0041H is "ready" on a GD350, "not ready" on a GD300-LIFT.
"""

from __future__ import annotations

import struct

from gateway.modbus.functions import (
    DIAGNOSTICS,
    READ_COILS,
    READ_DISCRETE_INPUTS,
    READ_HOLDING_REGISTERS,
    READ_INPUT_REGISTERS,
    WRITE_MULTIPLE_REGISTERS,
    WRITE_SINGLE_REGISTER,
)
from gateway.profile import (
    STANDARD_EXCEPTIONS,
    DriveProfile,
    ExceptionNames,
    Point,
    format_register,
    is_ram_address,
)
from gateway.profile.point_types import Table, word_key

BIT_TABLES = {READ_COILS: Table.COIL, READ_DISCRETE_INPUTS: Table.DISCRETE_INPUT}
"""The bit reads, by the table each reads: a device's coils and discrete inputs are points too."""
MAX_VALUES_SHOWN = 4
"""A 12-word poll names its first values and says how many more: a line stays one line."""


def describe_request(pdu: bytes, profile: DriveProfile | None) -> str:
    """What the request asks, without its answer (None: a drive the gateway has no profile of)."""
    if not pdu:
        return "empty request"
    function = pdu[0]
    if function in (READ_HOLDING_REGISTERS, READ_INPUT_REGISTERS) and len(pdu) == 5:
        start, count = struct.unpack(">HH", pdu[1:5])
        return f"read {_span(start, count, profile, _base(function, profile))}"
    if function == WRITE_SINGLE_REGISTER and len(pdu) == 5:
        address, value = struct.unpack(">HH", pdu[1:5])
        return f"write {_assignment(address, value, profile)}"
    if function == WRITE_MULTIPLE_REGISTERS and len(pdu) >= 6:
        start, count = struct.unpack(">HH", pdu[1:5])
        words = _words(pdu[6:])
        device = device_values(start, words, profile, Table.HOLDING, " = ")
        if device is not None:
            return f"write {_listed(device)}"
        shown = ", ".join(
            _assignment(start + i, w, profile) for i, w in enumerate(words[:MAX_VALUES_SHOWN])
        )
        more = f", +{count - MAX_VALUES_SHOWN} more" if count > MAX_VALUES_SHOWN else ""
        return f"write {shown}{more}"
    if function in BIT_TABLES and len(pdu) == 5:
        start, count = struct.unpack(">HH", pdu[1:5])
        table = BIT_TABLES[function].value.replace("_", " ")
        return f"read {table} {format_register(start)} ({count} bits)"
    if function == DIAGNOSTICS:
        return "loop-back 08H"
    return f"function {function:02X}H"


def exceptions_of(profile: DriveProfile | None) -> ExceptionNames:
    """The words of the drive's profile; the Modbus standard's for a device the gateway
    doesn't know (an address on the line that no drive of the configuration has)."""
    return STANDARD_EXCEPTIONS if profile is None else profile.exceptions


def describe(pdu: bytes, reply: bytes | None, profile: DriveProfile | None) -> str:
    """The request and, when the drive answered, what the answer says."""
    request = describe_request(pdu, profile)
    if reply is None:
        return request
    if reply and reply[0] & 0x80:
        code = reply[1] if len(reply) > 1 else 0
        return f"{request} → exception {code:02X}H {exceptions_of(profile).name(code)}"
    if not pdu:
        return request
    function = pdu[0]
    if function in (READ_HOLDING_REGISTERS, READ_INPUT_REGISTERS) and len(pdu) == 5:
        (start,) = struct.unpack(">H", pdu[1:3])
        words = _words(reply[2:])
        table = Table.INPUT if function == READ_INPUT_REGISTERS else Table.HOLDING
        device = device_values(start, words, profile, table, " ")
        if device is not None:
            return f"{request} → {_listed(device)}"
        base = _base(function, profile)
        shown = ", ".join(
            _value(start + i, w, profile, base, named=len(words) > 1)
            for i, w in enumerate(words[:MAX_VALUES_SHOWN])
        )
        more = f", +{len(words) - MAX_VALUES_SHOWN} more" if len(words) > MAX_VALUES_SHOWN else ""
        return f"{request} → {shown}{more}"
    if function in BIT_TABLES and len(pdu) == 5 and len(reply) >= 2:
        start, count = struct.unpack(">HH", pdu[1:5])
        # Bits from the first data byte's lowest on; a short reply shows what it holds.
        held = min(count, 8 * (len(reply) - 2))
        bits = [(reply[2 + i // 8] >> (i % 8)) & 1 for i in range(held)]
        device = device_values(start, bits, profile, BIT_TABLES[function], " ")
        raw = [f"{format_register(start + i)} {_text(bool(b))}" for i, b in enumerate(bits)]
        return f"{request} → {_listed(raw if device is None else device)}"
    if function == DIAGNOSTICS:
        return f"{request} → echoed" if reply == pdu else f"{request} → {reply.hex(' ')}"
    return f"{request} → ok"


def device_values(
    start: int, words: list[int], profile: DriveProfile | None, table: Table, between: str
) -> list[str] | None:
    """A device's words from `start` of `table` as its points' values, by address: each point
    the words hold whole decoded as MQTT publishes it (the profile's `telemetry`, the one
    decoder), any other word raw. None: not a device described by points."""
    if profile is None or not profile.typed_points:
        return None
    registers = {word_key(table, start + i): word for i, word in enumerate(words)}
    values = profile.telemetry(registers)
    shown: list[tuple[int, str]] = []
    covered: set[int] = set()
    for point in profile.typed_points:
        if point.table is not table or point.name not in values:
            continue
        unit = f" {point.unit}" if point.unit else ""
        shown.append((point.address, f"{point.name}{between}{_text(values[point.name])}{unit}"))
        covered.update(range(point.address, point.end))
    shown += [
        (start + i, f"{format_register(start + i)}{between}{_raw(word, table)}")
        for i, word in enumerate(words)
        if start + i not in covered
    ]
    return [text for _, text in sorted(shown, key=lambda item: item[0])]


def _raw(word: int, table: Table) -> str:
    return _text(bool(word)) if table.bits else f"{word:04X}H"


def _text(value: object) -> str:
    """A point's value as its MQTT state has it: on/off for a bool, a string as it is."""
    if isinstance(value, bool):
        return "on" if value else "off"
    return str(value)


def _listed(values: list[str]) -> str:
    more = len(values) - MAX_VALUES_SHOWN
    return ", ".join(values[:MAX_VALUES_SHOWN]) + (f", +{more} more" if more > 0 else "")


def _base(function: int, profile: DriveProfile | None) -> int:
    """Added to a read's addresses to look their points up: a device's points are per table
    (its input register 0002H is not its holding register 0002H, `point_types.word_key`); a
    drive's registers are one table, whichever function reads them."""
    if function == READ_INPUT_REGISTERS and profile is not None and profile.typed_points:
        return word_key(Table.INPUT, 0)
    return word_key(Table.HOLDING, 0)


def _span(start: int, count: int, profile: DriveProfile | None, base: int = 0) -> str:
    first = _name(start, profile, base)
    if count == 1:
        return first
    last = start + count - 1
    last_point = _point(last, profile, base)
    named_last = last_point is not None and first.startswith("P")
    last_name = last_point.label if last_point is not None and named_last else None
    return f"{first} … {last_name or format_register(last)} ({count} words)"


def _name(address: int, profile: DriveProfile | None, base: int = 0) -> str:
    """ "2100H state word 1", "P00.11", "P00.11 (RAM)", "0005H"."""
    point = _point(address, profile, base)
    if point is None:
        return format_register(address)
    if point.label.startswith("P"):
        return f"{point.label} (RAM)" if is_ram_address(address) else point.label
    named = point.description.split(":", 1)[0] if point.unit or point.description else ""
    if not named or point.description.startswith("not in the profile"):
        return point.label
    return f"{point.label} {named}"


def _assignment(address: int, value: int, profile: DriveProfile | None) -> str:
    point = _point(address, profile)
    if point is None:
        return f"{format_register(address)} = {value:04X}H"
    return f"{_name(address, profile)} = {point.show(value, profile)}"


def _value(
    address: int, value: int, profile: DriveProfile | None, base: int = 0, *, named: bool
) -> str:
    point = _point(address, profile, base)
    if point is None:
        return f"{value:04X}H"
    shown = point.show(value, profile)
    if point.meaning.value == "state_word_1":
        shown = f"{value:04X}H {shown.split('(', 1)[1].rstrip(')')}"
    if not named:
        return shown
    return f"{point.label if point.label.startswith('P') else format_register(address)} {shown}"


def _point(address: int, profile: DriveProfile | None, base: int = 0) -> Point | None:
    """The profile's point at `address` (in the table `base` says); None: no profile, or it
    doesn't name the address."""
    return None if profile is None else profile.point(base + address)


def _words(data: bytes) -> list[int]:
    return list(struct.unpack(f">{len(data) // 2}H", data[: len(data) // 2 * 2]))
