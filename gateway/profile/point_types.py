"""Typed points: how a device's registers hold a number, a text, a bit or a choice. No I/O.

A value of more than one register is the registers' bytes in an order devices disagree on; the
order is named by where the bytes A B C D of a big-endian 32-bit value arrive (A the highest):

    ABCD  registers in order, high byte first in each (Modbus's own order)
    CDAB  registers in reverse order ("word swap", most meters of the 2000s)
    BADC  registers in order, low byte first in each ("byte swap")
    DCBA  both: the whole value little-endian

A 64-bit value follows the same two rules over its four registers; a one-register value only
the byte rule. A published value is `raw * scale + offset`, an integer while both keep it one.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Final, TypeVar


class Table(StrEnum):
    """Modbus's four tables, each its own address space on a device."""

    HOLDING = "holding"
    INPUT = "input"
    COIL = "coil"
    DISCRETE_INPUT = "discrete_input"

    @property
    def bits(self) -> bool:
        return self in (Table.COIL, Table.DISCRETE_INPUT)


TABLE_KEY_BASE: Final = {
    Table.HOLDING: 0,
    Table.INPUT: 0x10000,
    Table.COIL: 0x20000,
    Table.DISCRETE_INPUT: 0x30000,
}
"""A polled word's key in a drive's register map: the holding table keeps its bare addresses
(every drive profile reads only those), each other table sits above 65535."""


def word_key(table: Table, address: int) -> int:
    return TABLE_KEY_BASE[table] + address


def table_of(key: int) -> tuple[Table, int]:
    """`word_key`'s table and address back."""
    table = next(t for t, base in TABLE_KEY_BASE.items() if base <= key < base + 0x10000)
    return table, key - TABLE_KEY_BASE[table]


class Order(StrEnum):
    ABCD = "ABCD"
    CDAB = "CDAB"
    BADC = "BADC"
    DCBA = "DCBA"

    @property
    def words_reversed(self) -> bool:
        return self in (Order.CDAB, Order.DCBA)

    @property
    def bytes_swapped(self) -> bool:
        return self in (Order.BADC, Order.DCBA)


class Kind(StrEnum):
    U16 = "u16"
    S16 = "s16"
    U32 = "u32"
    S32 = "s32"
    U64 = "u64"
    S64 = "s64"
    F32 = "f32"
    F64 = "f64"
    STRING = "string"
    BIT = "bit"
    ENUM = "enum"
    BOOL = "bool"
    """A coil or a discrete input: one bit of its own."""


_STRUCT: Final = {
    Kind.U16: "H",
    Kind.S16: "h",
    Kind.U32: "I",
    Kind.S32: "i",
    Kind.U64: "Q",
    Kind.S64: "q",
    Kind.F32: "f",
    Kind.F64: "d",
    Kind.ENUM: "H",
}
REGISTERS: Final = {kind: struct.calcsize(code) // 2 for kind, code in _STRUCT.items()}

Value = int | float | str | bool


@dataclass(frozen=True, slots=True)
class Limit:
    """A point's limit alarms (see `limit_alarms`): None where there is no such limit."""

    high: float | None = None
    low: float | None = None
    hysteresis: float = 0.0
    """How far back inside the limit the value must come for the alarm to clear."""
    delay_s: float = 0.0
    """How long a value must stay beyond (or back inside) before the alarm changes."""


@dataclass(frozen=True, slots=True)
class Reporting:
    """When a point's new value is news (report by exception; see `report_by_exception`)."""

    deadband: float = 0.0
    """A number must move by more than this (its unit) since it was last published."""
    deadband_percent: float = 0.0
    """... and by more than this share of the value last published."""
    min_interval_s: float = 0.0
    """A change is published no sooner than this after the point was last published."""
    max_interval_s: float | None = None
    """Published at least this often, changed or not (None: the gateway's
    `mqtt.publish_interval_s` only)."""


_Under = TypeVar("_Under", float, float | None)


@dataclass(frozen=True, slots=True)
class ReportRule:
    """What one level says of report by exception (a point in its device file, the file's
    defaults, the gateway's `mqtt.report.devices`): None where it leaves a key to the level
    under it."""

    deadband: float | None = None
    deadband_percent: float | None = None
    min_interval_s: float | None = None
    max_interval_s: float | None = None

    def over(self, under: ReportRule) -> ReportRule:
        """This level's keys where it sets them, `under`'s elsewhere."""
        return ReportRule(
            _own_or(self.deadband, under.deadband),
            _own_or(self.deadband_percent, under.deadband_percent),
            _own_or(self.min_interval_s, under.min_interval_s),
            _own_or(self.max_interval_s, under.max_interval_s),
        )

    def resolved(self, under: Reporting) -> Reporting:
        """The rule a point goes by: this level's keys over `under`'s (the gateway's)."""
        return Reporting(
            _own_or(self.deadband, under.deadband),
            _own_or(self.deadband_percent, under.deadband_percent),
            _own_or(self.min_interval_s, under.min_interval_s),
            _own_or(self.max_interval_s, under.max_interval_s),
        )


def _own_or(own: float | None, under: _Under) -> float | _Under:
    return under if own is None else own


@dataclass(frozen=True)
class TypedPoint:
    """One value of a device: where it is, how it is held, what it means."""

    name: str
    table: Table
    address: int
    kind: Kind
    registers: int = 1
    """How many registers (bits on a coil or discrete input: 1) it spans."""
    order: Order = Order.ABCD
    scale: float = 1.0
    offset: float = 0.0
    bit: int | None = None
    values: Mapping[int, str] = field(default_factory=dict)
    """An enumeration's words for each raw value."""
    unit: str = ""
    device_class: str | None = None
    state_class: str | None = None
    writable: bool = False
    interval_s: float | None = None
    """Its own poll interval (None: the device's)."""
    decimals: int | None = None
    """Published rounded to this many decimals (None: as decoded)."""
    report: ReportRule = ReportRule()
    """Its report by exception as its device file says (its own keys over the file's
    defaults); the gateway's `mqtt.report.devices` fills what neither sets."""
    limit: Limit = Limit()
    description: str = ""

    @property
    def end(self) -> int:
        """The address after its last register."""
        return self.address + self.registers

    def decode(self, words: Sequence[int]) -> Value:
        """The published value of its `registers` words as the device sent them."""
        if self.kind is Kind.BOOL:
            return bool(words[0])
        if self.kind is Kind.BIT:
            assert self.bit is not None
            return bool(words[0] >> self.bit & 1)
        data = _bytes(words, self.order)
        if self.kind is Kind.STRING:
            return data.split(b"\0", 1)[0].decode("latin-1").rstrip()
        (raw,) = struct.unpack(">" + _STRUCT[self.kind], data)
        if self.kind is Kind.ENUM:
            return self.values.get(raw, str(raw))
        if self.kind is Kind.F32:
            raw = shortest_f32(raw)
        value = self._scaled(raw)
        return value if self.decimals is None else round(value, self.decimals)

    def encode(self, value: object) -> tuple[int, ...]:
        """The words that hold `value` (as published: scaled, an enumeration's words). Raises
        ValueError saying why it can't be written."""
        if self.kind is Kind.BOOL:
            if not isinstance(value, bool):
                raise ValueError(f"{self.name} is on or off: give true or false")
            return (int(value),)
        if self.kind is Kind.STRING:
            if not isinstance(value, str):
                raise ValueError(f"{self.name} is a text: give a string")
            data = value.encode("latin-1", "replace")
            if len(data) > 2 * self.registers:
                raise ValueError(f"{self.name} holds at most {2 * self.registers} characters")
            return _words(data.ljust(2 * self.registers, b"\0"), self.order)
        raw = self._choice(value) if self.kind is Kind.ENUM else self._raw(value)
        return _words(struct.pack(">" + _STRUCT[self.kind], raw), self.order)

    def _scaled(self, raw: int | float) -> int | float:
        if isinstance(raw, int) and float(self.scale).is_integer() and self.offset.is_integer():
            return raw * int(self.scale) + int(self.offset)  # exact: a u64 is beyond a float
        return raw * self.scale + self.offset

    def _choice(self, value: object) -> int:
        for raw, words in self.values.items():
            if value == words:
                return raw
        raise ValueError(f"{self.name} must be one of {', '.join(self.values.values())}")

    def _raw(self, value: object) -> int | float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ValueError(f"{self.name} must be a number")
        if not math.isfinite(value):
            raise ValueError(f"{self.name} must be a finite number")
        if self.kind in (Kind.F32, Kind.F64):
            return (value - self.offset) / self.scale
        if isinstance(value, int) and self.scale == 1 and self.offset.is_integer():
            whole = value - int(self.offset)  # exact, as `_scaled` reads it
        else:
            whole = round((value - self.offset) / self.scale)
        low, high = _integer_range(self.kind)
        if not low <= whole <= high:
            raise ValueError(f"{self.name} = {value} is outside what a {self.kind} holds")
        return whole


def shortest_f32(value: float) -> float:
    """The shortest decimal that is the same 32-bit float: 230.1, not 230.10000610351562 (the
    float the device holds, as a person wrote it; JSON carries doubles)."""
    exact = struct.pack(">f", value)
    for digits in range(6, 10):
        shorter = float(f"{value:.{digits}g}")
        if struct.pack(">f", shorter) == exact:
            return shorter
    return value


def _integer_range(kind: Kind) -> tuple[int, int]:
    bits = 16 * REGISTERS[kind]
    if kind.value.startswith("s"):
        return -(1 << (bits - 1)), (1 << (bits - 1)) - 1
    return 0, (1 << bits) - 1


def _bytes(words: Sequence[int], order: Order) -> bytes:
    ordered = reversed(words) if order.words_reversed else words
    data = b"".join(struct.pack(">H", word & 0xFFFF) for word in ordered)
    if order.bytes_swapped:
        data = bytes(b for pair in zip(data[1::2], data[::2], strict=True) for b in pair)
    return data


def _words(data: bytes, order: Order) -> tuple[int, ...]:
    if order.bytes_swapped:
        data = bytes(b for pair in zip(data[1::2], data[::2], strict=True) for b in pair)
    words = struct.unpack(f">{len(data) // 2}H", data)
    return tuple(reversed(words)) if order.words_reversed else words


def no_typed_points(display_name: str) -> str:
    """Why a drive profile refuses a typed point's write."""
    return f"a {display_name} has no typed points: write a parameter or a register"
