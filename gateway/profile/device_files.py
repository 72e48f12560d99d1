"""Device files: the YAML that describes a Modbus device (a meter, a transmitter, remote I/O),
read into its `DeviceProfile` (`points_device`).

A device file gives the device's name and maker, where its map comes from (`source`), how it may
be read (`max_registers`, `max_bits`, `max_gap`, `interval_ms`), its report-by-exception defaults,
and its points, each a telemetry key (see `point_types` for the types and orders). Shipped files
live in `data/devices/` and are named by their file name (`model: sdm630`); a site's own file is
named by its path (`model: file:/etc/invt-gateway/devices/mymeter.yaml`).

A device file is checked whole when it is loaded: every mistake is named by its file and key path
("mymeter.yaml: points.voltage.type: ..."), overlapping points and points the device can't hold
(a 32-bit value in a coil, a bit 16, a writable input register) included.
"""

from __future__ import annotations

from collections.abc import Callable
from importlib import resources
from pathlib import Path
from typing import Annotated, Any, Final, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from gateway.errors import DeviceFileError
from gateway.profile.addressing import format_register, parse_register
from gateway.profile.limit_alarms import alarm_name, limit_sides
from gateway.profile.point_types import (
    REGISTERS,
    Kind,
    Limit,
    Order,
    ReportRule,
    Table,
    TypedPoint,
)
from gateway.profile.points_device import DeviceProfile
from gateway.profile.read_plan import Limits

FILE_PREFIX: Final = "file:"
"""`model: file:PATH`: a site's own device file."""
MODBUS_MAX_REGISTERS: Final = 125
MODBUS_MAX_BITS: Final = 2000
_NAME = r"^[a-z][a-z0-9_]*$"


# -- the file's shape ------------------------------------------------------------------------------


class _Section(BaseModel):
    # The docstring under each field is its description: the Other Modbus devices page's table
    # of a device file's keys is generated from it.
    model_config = ConfigDict(extra="forbid", frozen=True, use_attribute_docstrings=True)


class _PointSpec(_Section):
    table: Table = Table.HOLDING
    """Which table the point is in: `holding` (03H), `input` (04H), `coil` (01H) or
    `discrete_input` (02H)."""
    address: int | str
    """The address on the wire (from 0): 16, "0x0010" or "0010H"."""
    type: Kind = Kind.U16
    """How the registers read: `string` needs `registers`, `bit` needs `bit`, `enum` needs
    `values`; `bool` is for coils and discrete inputs."""
    registers: int | None = Field(None, ge=1, le=MODBUS_MAX_REGISTERS)
    """A string's length in registers (other types know their own)."""
    bit: int | None = None
    """With `type: bit`: which bit of the register, 0..15."""
    order: Order | None = None
    """Word and byte order of a multi-register value: ABCD, CDAB (word swap), BADC or DCBA;
    default the file's `order`."""
    scale: float = 1.0
    """The value published is `raw * scale + offset`; not 0."""
    offset: float = 0.0
    """Added after `scale`."""
    values: dict[int, str] | None = None
    """With `type: enum`: raw value → its name (`{0: "off", 1: local}`)."""
    unit: str = ""
    """The value's unit, shown by Home Assistant and the console."""
    device_class: str | None = None
    """Home Assistant's device class (`energy`, `door`, `running`, `problem`...)."""
    state_class: Literal["measurement", "total", "total_increasing"] | None = None
    """Home Assistant's state class: `measurement`, `total` or `total_increasing`."""
    writable: bool = False
    """`<base>/<drive>/set` may write it (holding registers: 06H or one 10H; coils: 05H; never a
    bit of a register); Home Assistant gets a number or a switch."""
    interval_ms: float | None = Field(None, gt=0)
    """This point's poll interval; default the file's `interval_ms`."""
    decimals: int | None = Field(None, ge=0, le=9)
    """Published rounded to this many decimals (a scaled count: 12.5, not 12.500000001)."""
    description: str = ""
    """What the point is, in words (shown in the console)."""
    deadband: float | None = Field(None, ge=0)
    """Report by exception: the value must move by more than this (in its unit) since last
    published; default the file's."""
    deadband_percent: float | None = Field(None, ge=0)
    """... and by more than this share of the value last published; default the file's."""
    min_interval_ms: float | None = Field(None, ge=0)
    """A change is published no sooner than this after the point was last published; default the
    file's."""
    max_interval_ms: float | None = Field(None, gt=0)
    """Published at least this often, changed or not; default the file's (report by exception,
    `report_by_exception`)."""
    high: float | None = None
    """Limit alarm: `alarm_raised` when the value stays above this for `alarm_delay_ms`."""
    low: float | None = None
    """Limit alarm: `alarm_raised` when the value stays below this for `alarm_delay_ms`."""
    hysteresis: float = Field(0.0, ge=0)
    """How far back inside the limit the value must come for the alarm to clear."""
    alarm_delay_ms: float = Field(0.0, ge=0)
    """How long beyond `high` or `low` (or back inside) before the alarm is raised (or cleared):
    `alarm_raised` and `alarm_cleared` events (`limit_alarms`)."""

    @field_validator("address")
    @classmethod
    def _address(cls, value: int | str) -> int:
        address = value if isinstance(value, int) else parse_register(str(value))
        if not 0 <= address <= 0xFFFF:
            raise ValueError("must be 0..65535 (0000H...FFFFH), the address on the wire")
        return address

    @field_validator("scale")
    @classmethod
    def _scale(cls, value: float) -> float:
        if value == 0:
            raise ValueError("must not be 0")
        return value


class _DeviceSpec(_Section):
    name: str = Field(min_length=1)
    """The device's name, shown in Home Assistant and the console."""
    manufacturer: str = ""
    """Who makes it (Home Assistant's manufacturer)."""
    source: str = Field(min_length=1)
    """Where the register map comes from (a manual's page): every device file says."""
    aliases: tuple[str, ...] = ()
    """Other names `model:` takes for a shipped file."""
    max_registers: int = Field(MODBUS_MAX_REGISTERS, ge=1, le=MODBUS_MAX_REGISTERS)
    """The most registers one request may ask for."""
    max_bits: int = Field(MODBUS_MAX_BITS, ge=1, le=MODBUS_MAX_BITS)
    """The most coils or discrete inputs one request may ask for."""
    max_gap: int = Field(0, ge=0, le=MODBUS_MAX_REGISTERS)
    """Unused registers a request may read across to join two points' reads."""
    interval_ms: float = Field(1000, gt=0)
    """The poll interval of every point that doesn't set its own."""
    order: Order = Order.ABCD
    """The points' order unless a point says otherwise."""
    unconfirmed: tuple[str, ...] = ()
    """What the manual didn't settle, in words, said where the device's facts show."""
    deadband: float | None = Field(None, ge=0)
    """Report by exception, every point's unless it sets its own: a number must move by more
    than this (in its unit); what neither sets, the gateway's `mqtt.report.devices` does."""
    deadband_percent: float | None = Field(None, ge=0)
    """... and by more than this share of the value last published."""
    min_interval_ms: float | None = Field(None, ge=0)
    """A change is published no sooner than this after the point was last published."""
    max_interval_ms: float | None = Field(None, gt=0)
    """Every point is published at least this often, changed or not (default:
    `mqtt.publish_interval_s`)."""
    points: dict[Annotated[str, Field(pattern=_NAME)], _PointSpec] = Field(min_length=1)
    """The device's points by name (lower case, digits, `_`): each a key of its MQTT state."""


DEVICE_FILE: Final[type[BaseModel]] = _DeviceSpec
"""The model of a device file, for its reference (`gateway.config.reference`)."""


# -- loading ---------------------------------------------------------------------------------------


def shipped_devices() -> tuple[DeviceProfile, ...]:
    """The device files in the package (`data/devices/*.yaml`), by file name."""
    folder = resources.files("gateway.profile").joinpath("data", "devices")
    return tuple(
        device_profile(entry.name.removesuffix(".yaml"), entry.read_text(), entry.name)
        for entry in sorted(folder.iterdir(), key=lambda e: e.name)
        if entry.name.endswith(".yaml")
    )


def device_file_profile(model: str) -> DeviceProfile:
    """`file:PATH`'s profile. Raises DeviceFileError."""
    path = Path(model.removeprefix(FILE_PREFIX).strip())
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise DeviceFileError(f"device file {path}: {exc.strerror or exc}") from None
    return device_profile(model, text, str(path))


def device_profile(key: str, text: str, where: str) -> DeviceProfile:
    """The profile of a device file's `text` (`where` names it in errors)."""
    try:
        data: Any = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise DeviceFileError(f"{where}: not YAML: {exc}") from None
    try:
        spec = _DeviceSpec.model_validate(data)
    except ValidationError as exc:
        first = exc.errors()[0]
        path = ".".join(str(part) for part in first["loc"]) or "(top)"
        more = f" (and {exc.error_count() - 1} more)" if exc.error_count() > 1 else ""
        raise DeviceFileError(f"{where}: {path}: {first['msg']}{more}") from None
    points = tuple(_typed(name, point, spec, where) for name, point in spec.points.items())
    _check_overlaps(points, where)
    _check_alarm_flags(points, where)
    limits = Limits(spec.max_registers, spec.max_bits, spec.max_gap, spec.interval_ms / 1000)
    for point in points:
        most = limits.most(point.table)
        if point.registers > most:
            raise DeviceFileError(
                f"{where}: points.{point.name}: {point.registers} registers, more than the "
                f"device's max_registers ({most}): it could never be read in one request"
            )
    return DeviceProfile(
        key,
        spec.name,
        points,
        limits,
        manufacturer=spec.manufacturer,
        aliases=spec.aliases,
        source=spec.source,
        unconfirmed=spec.unconfirmed,
    )


def _typed(name: str, spec: _PointSpec, device: _DeviceSpec, where: str) -> TypedPoint:
    def wrong(key: str, why: str) -> DeviceFileError:
        return DeviceFileError(f"{where}: points.{name}.{key}: {why}")

    registers = _registers(spec, wrong)
    assert isinstance(spec.address, int)  # the validator made it one
    _check(spec, spec.address, registers, wrong)
    order = spec.order or device.order
    if spec.type is Kind.STRING and order.words_reversed:
        raise wrong("order", "a string's registers come in order: ABCD or BADC")
    return TypedPoint(
        name=name,
        table=spec.table,
        address=spec.address,
        kind=spec.type,
        registers=registers,
        order=order,
        scale=spec.scale,
        offset=spec.offset,
        bit=spec.bit,
        values=dict(spec.values or {}),
        unit=spec.unit,
        device_class=spec.device_class,
        state_class=spec.state_class,
        writable=spec.writable,
        interval_s=None if spec.interval_ms is None else spec.interval_ms / 1000,
        decimals=spec.decimals,
        description=spec.description,
        report=_report(spec, device),
        limit=Limit(spec.high, spec.low, spec.hysteresis, spec.alarm_delay_ms / 1000),
    )


def _check(
    spec: _PointSpec, address: int, registers: int, wrong: Callable[[str, str], DeviceFileError]
) -> None:
    """What a point's keys must agree on: its table and type, a bit's number, an enum's values,
    what may be written, a number's limits."""
    if address + registers > 0x10000:
        raise wrong("address", f"its {registers} registers pass FFFFH")
    if spec.table.bits != (spec.type is Kind.BOOL):
        raise wrong(
            "type",
            "a coil or discrete input is a bool, and a bool is a coil or a discrete input",
        )
    if (spec.type is Kind.BIT) != (spec.bit is not None) or not 0 <= (spec.bit or 0) <= 15:
        raise wrong("bit", "a bit point needs bit: 0..15, and only a bit point has one")
    if (spec.type is Kind.ENUM) != bool(spec.values):
        raise wrong("values", "an enum needs values (raw: words), and only an enum has them")
    if spec.writable and spec.table in (Table.INPUT, Table.DISCRETE_INPUT):
        raise wrong("writable", "input registers and discrete inputs are read-only on every device")
    if spec.writable and spec.type is Kind.BIT:
        raise wrong(
            "writable", "a bit can't be written alone (its register's other bits would be too)"
        )
    limited = spec.high is not None or spec.low is not None
    if limited and spec.type in (Kind.STRING, Kind.ENUM, Kind.BIT, Kind.BOOL):
        raise wrong("high" if spec.high is not None else "low", "only a number has limits")
    if spec.high is not None and spec.low is not None and spec.low >= spec.high:
        raise wrong("low", f"must be below high ({spec.high:g})")


def _report(spec: _PointSpec, device: _DeviceSpec) -> ReportRule:
    """The point's own report-by-exception keys over its file's defaults."""
    return _rule(spec).over(_rule(device))


def _rule(level: _PointSpec | _DeviceSpec) -> ReportRule:
    def seconds(ms: float | None) -> float | None:
        return None if ms is None else ms / 1000

    return ReportRule(
        level.deadband,
        level.deadband_percent,
        seconds(level.min_interval_ms),
        seconds(level.max_interval_ms),
    )


def _registers(spec: _PointSpec, wrong: Any) -> int:
    if spec.type is Kind.STRING:
        if spec.registers is None:
            raise wrong("registers", "a string needs its length in registers")
        return spec.registers
    if spec.registers is not None:
        raise wrong("registers", f"only a string has registers: a {spec.type} knows its own")
    return REGISTERS.get(spec.type, 1)


def _check_overlaps(points: tuple[TypedPoint, ...], where: str) -> None:
    """Two points on one register: a mistake, unless both are different bits of it."""
    claimed: dict[tuple[Table, int], TypedPoint] = {}
    bits: set[tuple[Table, int, int]] = set()
    for point in points:
        for address in range(point.address, point.end):
            if point.kind is Kind.BIT:
                assert point.bit is not None
                key = (point.table, address, point.bit)
                if key in bits:
                    raise DeviceFileError(
                        f"{where}: points.{point.name}: bit {point.bit} of "
                        f"{format_register(address)} is another point's too"
                    )
                bits.add(key)
                continue
            other = claimed.setdefault((point.table, address), point)
            if other is not point:
                raise DeviceFileError(
                    f"{where}: points.{point.name}: overlaps points.{other.name} at "
                    f"{point.table.value} register {format_register(address)}"
                )


def _check_alarm_flags(points: tuple[TypedPoint, ...], where: str) -> None:
    """A limit alarm's flag is a key of the device's state beside its points (`alarm_name`): a
    point of that name would be overwritten by it."""
    names = {point.name for point in points}
    for point in points:
        for side, _ in limit_sides(point.limit):
            flag = alarm_name(point.name, side)
            if flag in names:
                raise DeviceFileError(
                    f"{where}: points.{flag}: is the state's key of points.{point.name}'s "
                    f"{side} alarm; give the point another name"
                )
