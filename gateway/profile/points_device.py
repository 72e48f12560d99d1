"""A Modbus device described by a device file (a meter, a transmitter, remote I/O): its
`DeviceProfile`, one implementation of `DriveProfile`. `device_files` reads the files.

Its telemetry is its points, each decoded from the words the poller read (every table's, kept
under `point_types.word_key`); its reads are planned from the points (`read_plan`); a writable
point is written through `point_write`. It has no faults, commands or parameters of a drive.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import cached_property
from typing import ClassVar, Final

from gateway.profile.addressing import format_register, parse_register
from gateway.profile.faults import FaultTable
from gateway.profile.not_a_drive import NotADrive
from gateway.profile.parameters import Parameter
from gateway.profile.point_types import Kind, Table, TypedPoint, Value, table_of, word_key
from gateway.profile.points import Point
from gateway.profile.protocol import PollGroup, RegisterWrite
from gateway.profile.read_plan import Limits, plan_reads
from gateway.profile.telemetry import Telemetry

NO_FAULTS: Final = FaultTable("no fault table", {})


@dataclass(frozen=True)
class DeviceProfile(NotADrive):
    no_commands_hint: ClassVar[str] = ": write its points"

    key: str
    display_name: str
    typed_points: tuple[TypedPoint, ...]
    limits: Limits
    manufacturer: str = ""
    aliases: tuple[str, ...] = ()
    source: str = ""
    unconfirmed: tuple[str, ...] = ()
    identification: tuple[int, ...] = ()
    split_by_default: bool = False
    ram_writes_supported: bool = False
    faults: FaultTable = NO_FAULTS
    commands: tuple[str, ...] = ()
    parameters: tuple[Parameter, ...] = ()
    max_frequency_hz: float = 0.0
    max_frequency_parameter: Parameter | None = None
    _by_name: Mapping[str, TypedPoint] = field(default_factory=dict, compare=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_by_name", {p.name: p for p in self.typed_points})

    @property
    def max_words(self) -> int:
        return self.limits.max_registers

    @cached_property
    def poll_groups(self) -> tuple[PollGroup, ...]:
        return plan_reads(self.typed_points, self.limits)

    @property
    def telemetry_keys(self) -> frozenset[str]:
        return frozenset(self._by_name)

    def telemetry(self, registers: Mapping[int, int]) -> Telemetry:
        """Each point whose registers have all been read, decoded."""
        telemetry: Telemetry = {}
        for point in self.typed_points:
            value = _read(point, registers)
            if value is not None:
                telemetry[point.name] = value
        return telemetry

    def point(self, address: int) -> Point | None:
        """The point at `address`: a holding register's, or another table's at its
        `point_types.word_key` (what the traffic monitor and the field tools show)."""
        table, address = table_of(address)
        for typed in self.typed_points:
            if typed.table is table and typed.address <= address < typed.end:
                part = address - typed.address + 1
                which = "" if typed.registers == 1 else f" (register {part} of {typed.registers})"
                return Point(typed.name, address, f"{typed.name}{which}", unit=typed.unit)
        return None

    def resolve(self, text: str) -> Point:
        """A point the field tools (`read`, `write`) can carry: one holding register of a
        16-bit integer; another point is refused by name (they would read the wrong table, or
        one register of a wider value); an address is taken as a holding register."""
        spelled = text.strip()
        typed = self._by_name.get(spelled.lower())
        if typed is not None:
            if typed.table is not Table.HOLDING or typed.kind not in (Kind.U16, Kind.S16):
                raise ValueError(
                    f"{typed.name} is a {typed.kind} in the {typed.table.value} table: the field "
                    "tools carry single holding registers; read it from MQTT or the console"
                )
            described = typed.description or typed.name
            decimals = _decimals_of(typed.scale) if typed.offset == 0 else 0
            return Point(
                typed.name,
                typed.address,
                described,
                decimals=decimals,
                unit=typed.unit,
                signed=typed.kind is Kind.S16,
            )
        address = parse_register(spelled)
        return self.point(address) or Point(
            format_register(address), address, "not in the device file: shown raw"
        )

    def point_write(self, name: str, value: object) -> RegisterWrite:
        point = self._by_name.get(name)
        if point is None:
            writable = ", ".join(p.name for p in self.typed_points if p.writable) or "none"
            raise ValueError(f"{self.display_name} has no point {name!r}: writable are {writable}")
        if not point.writable:
            raise ValueError(f"{name} of {self.display_name} is not writable")
        return RegisterWrite(point.address, point.encode(value), table=point.table)


def _decimals_of(scale: float) -> int:
    """A scale of 0.1 as the field tools' decimals (1); any other scale (or an offset) shows
    the raw word."""
    for decimals in range(5):
        if scale == 10.0**-decimals:
            return decimals
    return 0


def _read(point: TypedPoint, registers: Mapping[int, int]) -> Value | None:
    words = []
    for address in range(point.address, point.end):
        word = registers.get(word_key(point.table, address))
        if word is None:
            return None
        words.append(word)
    return point.decode(words)
