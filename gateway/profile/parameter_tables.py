"""Each series' function-parameter table (Pxx.yy), loaded from the data files beside this module.

`data/parameter_sources.yaml` says, series by series, which tables make up its parameter set
and in what order (the first table that has a code wins), and where each table's groups come
from (manual, section, pages). A table is a CSV file in `data/`, one row per function code:

    code,name,unit,decimals,minimum,maximum,default,change,choices,minimum_from,maximum_from,note
    P00.03,Max. output frequency,Hz,2,0,400.00,50.00,◎,,P00.04,,

- values are written as the manual writes them (50.00, -300.0, 0x1FF); `decimals` is the
  register's scale (50.00 Hz is 5000 on the wire); hex values mark a bit mask or a digit code;
- `default` is empty where the manual says "depends on model";
- `change` is the manual's mark: ○ writable any time, ◎ not while the drive runs, ● read-only;
- `choices` are the manual's words for each value, `|`-separated ("0: keypad|1: terminal");
  an entry that is not "N: words" or "N-M: words" says how to read the bits or digits;
- `minimum_from`/`maximum_from` name the parameter whose value is the bound (P00.04 lies
  within P00.05 ... P00.03);
- `note` says what the source leaves unclear.

A series whose own manual tables were not reachable takes another series' table, marked
unconfirmed in every row (`Parameter.confirmed`), as the fault tables do (see `faults`).
"""

from __future__ import annotations

import csv
import io
import re
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from functools import cache
from importlib import resources
from types import MappingProxyType
from typing import Any, Final

import yaml

from gateway.errors import TableError
from gateway.profile.addressing import RAM_BIT, format_parameter, parse_parameter, parse_register
from gateway.profile.parameters import PARAMETERS, Parameter

COLUMNS: Final = (
    "code", "name", "unit", "decimals", "minimum", "maximum", "default", "change", "choices",
    "minimum_from", "maximum_from", "note",
)  # fmt: skip
CHANGE_MARKS: Final = {"○": "any time", "◎": "stopped only", "●": "read-only"}
COMMON: Final = "common"
"""The gateway's earlier table of 25 parameters (`parameters.PARAMETERS`), kept as a layer."""
_CHOICE: Final = re.compile(r"^(\d+)(?:-(\d+))?: (.+)$")
_NUMBER: Final = re.compile(r"P\d{1,2}\.\d{1,2}|\d[0-9A-F]{0,3}H|0x[0-9A-F]{1,4}", re.IGNORECASE)
"""How a parameter's number is written: P00.03 (the manual), 0003H or 0x0003 (the wire)."""
_MAX_EXPANDED: Final = 32
"""A choice range ("9-11: reserved") is listed value by value up to this many values; a longer
one ("100-150: braking coefficient") is a span of settings, kept as a hint."""


@dataclass(frozen=True)
class ParameterTable:
    """One series' parameters, in code order, with lookups by name and by register address."""

    series: str
    rows: tuple[Parameter, ...]
    sources: Mapping[str, str] = field(default_factory=lambda: MappingProxyType({}))
    """Group ("P00") → where its rows come from, in words."""
    _by_address: Mapping[int, Parameter] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        # frozen: the index is built once, here
        object.__setattr__(self, "_by_address", {row.address: row for row in self.rows})

    def at(self, address: int) -> Parameter | None:
        """The parameter at a register address (without the RAM bit), or None."""
        return self._by_address.get(address)

    def named(self, name: str) -> Parameter | None:
        """The parameter called `name` ("P00.11", any case), or None."""
        try:
            return self.at(parse_parameter(name))
        except ValueError:
            return None

    @property
    def groups(self) -> tuple[str, ...]:
        """Every group the table has a row of ("P00", "P01" ... "P24"), in order."""
        return tuple(dict.fromkeys(row.group for row in self.rows))

    def find(self, text: str) -> tuple[Parameter, ...]:
        """The rows a person means by `text`: a number as the manual or the wire writes it
        ("P00.03", "p0.3", "0003H", "0x0003") gives that row; other words give every row whose
        name holds them all, in any order and letter case ("acc time", "Max. output")."""
        spelled = text.strip()
        if not spelled:
            return ()
        if _NUMBER.fullmatch(spelled):
            try:
                found = self.at(parse_register(spelled) & ~RAM_BIT)
            except ValueError:
                return ()
            return () if found is None else (found,)
        wanted = spelled.casefold().split()
        return tuple(
            row
            for row in self.rows
            if all(word in f"{row.name} {row.description}".casefold() for word in wanted)
        )

    @property
    def unconfirmed_groups(self) -> tuple[str, ...]:
        """Groups with a row taken from another series' table."""
        return tuple(sorted({row.group for row in self.rows if not row.confirmed}))


def read_rows(text: str, source: str) -> list[Parameter]:
    """The rows of one CSV table, each checked: range holds the default, codes unique, in order."""
    reader = csv.DictReader(io.StringIO(text))
    if tuple(reader.fieldnames or ()) != COLUMNS:
        raise TableError(f"{source}: the header must be {','.join(COLUMNS)}")
    rows: list[Parameter] = []
    for record in reader:
        where = f"{source}:{reader.line_num}"
        row = _row({k: (v or "").strip() for k, v in record.items()}, where)
        if rows and row.address <= rows[-1].address:
            raise TableError(f"{where}: {row.name} is not after {rows[-1].name} (codes in order)")
        rows.append(row)
    return rows


def _row(record: Mapping[str, str], where: str) -> Parameter:
    try:
        name = format_parameter(parse_parameter(record["code"]))
    except ValueError as exc:
        raise TableError(f"{where}: code: {exc}") from None
    if not record["name"]:
        raise TableError(f"{where}: name: empty")
    if record["change"] not in CHANGE_MARKS:
        raise TableError(f"{where}: change: {record['change']!r} is none of ○ ◎ ●")
    decimals = _integer(record["decimals"], where, "decimals")
    hexadecimal = any(record[key].lower().startswith("0x") for key in ("minimum", "maximum"))
    minimum = _number(record["minimum"], decimals, where, "minimum", 0)
    maximum = _number(record["maximum"], decimals, where, "maximum", 0xFFFF)
    if minimum < -0x8000 or maximum > (0x7FFF if minimum < 0 else 0xFFFF) or minimum > maximum:
        raise TableError(f"{where}: range {minimum}..{maximum} does not fit one register")
    default_known = bool(record["default"])
    default = _number(record["default"], decimals, where, "default", max(minimum, 0))
    if not minimum <= default <= maximum:
        raise TableError(f"{where}: default {record['default']} outside the range")
    choices, hint = _choices(record["choices"], where)
    return Parameter(
        name,
        record["name"],
        decimals,
        record["unit"],
        default=default & 0xFFFF,
        minimum=minimum,
        maximum=maximum,
        minimum_from=_reference(record["minimum_from"], where),
        maximum_from=_reference(record["maximum_from"], where),
        read_only=record["change"] == "●",
        locked_while_running=record["change"] == "◎",
        choices=choices,
        hint=hint,
        hexadecimal=hexadecimal,
        default_known=default_known,
        note=record["note"],
    )


def _integer(text: str, where: str, column: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise TableError(f"{where}: {column}: {text!r} is not a whole number") from None


def _number(text: str, decimals: int, where: str, column: str, empty: int) -> int:
    """The register's number for a value as the manual writes it ("50.00" at 2 decimals: 5000)."""
    if not text:
        return empty
    try:
        if text.lower().startswith("0x"):
            return int(text, 16)
        value = float(text)
    except ValueError:
        raise TableError(f"{where}: {column}: {text!r} is not a number") from None
    scaled = value * float(10**decimals)
    number = round(scaled)
    if abs(number - scaled) > 1e-6 * max(1.0, abs(scaled)):
        raise TableError(f"{where}: {column}: {text} has more than {decimals} decimals")
    return number


def _reference(text: str, where: str) -> str | None:
    if not text:
        return None
    try:
        return format_parameter(parse_parameter(text))
    except ValueError as exc:
        raise TableError(f"{where}: bound {text!r}: {exc}") from None


def _choices(text: str, where: str) -> tuple[tuple[tuple[int, str], ...], str]:
    choices: list[tuple[int, str]] = []
    hints: list[str] = []
    for entry in filter(None, (part.strip() for part in text.split("|"))):
        match = _CHOICE.match(entry)
        if match is None:
            hints.append(entry)
            continue
        low = int(match[1])
        high = int(match[2]) if match[2] else low
        if high < low:
            raise TableError(f"{where}: choices: {entry!r} is an empty range")
        if high - low >= _MAX_EXPANDED:  # a span of settings ("100-150: coefficient")
            hints.append(entry)
            continue
        choices.extend((value, match[3]) for value in range(low, high + 1))
    values = [value for value, _ in choices]
    if len(set(values)) != len(values):
        raise TableError(f"{where}: choices: a value is listed twice")
    return tuple(choices), "; ".join(hints)


# ------------------------------------------------------------------------------ the series


def _data(name: str) -> str:
    return resources.files("gateway.profile").joinpath("data", name).read_text(encoding="utf-8")


@cache
def sources() -> Mapping[str, Any]:
    """`data/parameter_sources.yaml`, as loaded."""
    document = yaml.safe_load(_data("parameter_sources.yaml"))
    if not isinstance(document, dict) or not {"tables", "series"} <= document.keys():
        raise TableError("parameter_sources.yaml: expected 'tables' and 'series'")
    return MappingProxyType(document)


@cache
def _table_rows(table: str) -> tuple[Parameter, ...]:
    """The rows of one table with their source: common (in code) or a CSV file."""
    described = sources()["tables"][table]
    if table == COMMON:
        rows: list[Parameter] = list(PARAMETERS)
    else:
        rows = read_rows(_data(described["file"]), described["file"])
    groups: Mapping[str, str] = described.get("groups", {})
    actions: Mapping[str, str] = described.get("actions", {})
    resets: Mapping[str, list[str]] = described.get("reinitialises", {})
    factory: Mapping[str, str] = described.get("factory", {})
    document = described["document"]
    result = []
    for row in rows:
        if groups and row.group not in groups:
            raise TableError(f"{described.get('file', table)}: {row.name}: no source for its group")
        pages = groups.get(row.group, "")
        source = f"{document}, {pages}" if pages else document
        reset = tuple(format_parameter(parse_parameter(name)) for name in resets.get(row.name, ()))
        result.append(
            replace(
                row,
                source=source,
                action=actions.get(row.name, ""),
                reinitialises=reset,
                factory=factory.get(row.name, ""),
            )
        )
    names = {row.name for row in result}
    named = set(actions) | set(resets) | set(factory) | {n for ns in resets.values() for n in ns}
    unknown = named - names
    if unknown:
        raise TableError(f"parameter_sources.yaml: {table}: no such rows: {sorted(unknown)}")
    return tuple(result)


def table_rows(table: str) -> tuple[Parameter, ...]:
    """One table of `parameter_sources.yaml` (`common`, `gd200a`), its rows with their sources,
    before any series layers it."""
    return _table_rows(table)


def _simulated_default(row: Parameter) -> Parameter:
    """A "depends on model" default starts a simulated drive at the common table's value for
    that code when it fits (10.0 s ramps), else at the range's lower bound."""
    if row.default_known:
        return row
    common = next((p for p in PARAMETERS if p.address == row.address), None)
    if common is not None and row.minimum <= row.number(common.default) <= row.maximum:
        return replace(row, default=common.default)
    return row


@cache
def series_table(key: str) -> ParameterTable:
    """The parameter table of the series a profile is keyed by ("gd350"); `common` for one
    `parameter_sources.yaml` does not list (the generic Modbus device)."""
    layers = sources()["series"].get(key, [{"table": COMMON}])
    rows: dict[int, Parameter] = {}
    group_sources: dict[str, list[str]] = {}
    for layer in layers:
        confirmed = bool(layer.get("confirmed", True))
        for row in _table_rows(layer["table"]):
            if row.address in rows:
                continue
            taken = _simulated_default(row if confirmed else replace(row, confirmed=False))
            rows[row.address] = taken
            label = taken.source if confirmed else f"{taken.source} (unconfirmed for {key})"
            if label not in group_sources.setdefault(row.group, []):
                group_sources[row.group].append(label)
    ordered = tuple(rows[address] for address in sorted(rows))
    return ParameterTable(
        key,
        ordered,
        MappingProxyType({group: "; ".join(labels) for group, labels in group_sources.items()}),
    )
