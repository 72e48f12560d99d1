"""The drives' reference, read from the profiles and their data files: every model with its
identification, fault table and differences, INVT's communication registers, every fault table,
and every function-parameter table with the document its rows come from.

The documentation site's Drive series and Parameter tables pages are generated from these at
build time (docs/hooks/generated.py), so they say what the gateway does. Nothing here lists
models or tables by hand: a series added to a profile module, a table added to
`data/parameter_sources.yaml`, appears by itself.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator

from gateway.profile.addressing import format_register
from gateway.profile.faults import FaultTable
from gateway.profile.invt import InvtProfile
from gateway.profile.invt_codes import FAULT_CODE
from gateway.profile.models import PROFILES
from gateway.profile.parameter_tables import (
    CHANGE_MARKS,
    ParameterTable,
    series_table,
    sources,
    table_rows,
)
from gateway.profile.parameters import Parameter
from gateway.profile.protocol import DriveProfile
from gateway.profile.registers import COMMUNICATION_REGISTERS, RUNNING_VALUES, Register

_COMMON_INVT = InvtProfile("", "")
"""An INVT series with no difference: what each series' row is held against."""


def _cell(text: object) -> str:
    return " ".join(str(text).split()).replace("|", "\\|")


def _table(header: Iterable[str], rows: Iterable[Iterable[object]]) -> str:
    heads = list(header)
    lines = ["| " + " | ".join(heads) + " |", "|" + "---|" * len(heads)]
    lines += ["| " + " | ".join(_cell(value) for value in row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def _codes(profile: DriveProfile) -> str:
    if not profile.identification:
        return "none (not asked)"
    codes = " or ".join(format_register(code) for code in profile.identification)
    placeholder = isinstance(profile, InvtProfile) and not profile.identification_confirmed
    return f"{codes} (placeholder)" if placeholder else codes


def _fault_range(table: FaultTable) -> str:
    if not table.entries:
        return table.name
    return f"{table.name}, {min(table.entries)}-{max(table.entries)}"


def differences(profile: InvtProfile) -> list[str]:
    """What sets an INVT series apart from the common map, in words."""
    common = _COMMON_INVT
    found = []
    extra = [r for r in profile.fault_registers if r != FAULT_CODE]
    if extra:
        found.append("fault code also at " + ", ".join(map(format_register, extra)))
    if profile.ready_bit_set_means_ready != common.ready_bit_set_means_ready:
        found.append("2101H bit 0 = 0 means ready")
    if profile.manufacturer_group is not None:
        found.append(f"P{profile.manufacturer_group:02d} manufacturer group (not read or written)")
    if profile.motors != common.motors:
        found.append(f"2101H reports motors 1-{profile.motors}")
    if profile.virtual_input_bits != common.virtual_input_bits:
        found.append(f"{profile.virtual_input_bits} virtual inputs")
    if profile.max_words != common.max_words:
        found.append(f"at most {profile.max_words} words a request")
    for register, decimals in profile.decimals_overrides.items():
        found.append(f"{register} with {decimals} decimals")
    if not profile.ram_writes_supported:
        found.append("no RAM-only parameter writes")
    return found


def series_markdown() -> str:
    """Every model `model:` takes, with its maker, 2103H codes, fault table, request limit and
    what sets it apart; unconfirmed facts in bold."""
    rows = []
    for profile in PROFILES.values():
        name = f"`{profile.key}`"
        if profile.aliases:
            name += " (" + ", ".join(f"`{alias}`" for alias in profile.aliases) + ")"
        notes = differences(profile) if isinstance(profile, InvtProfile) else []
        notes += [f"**unconfirmed: {fact}**" for fact in profile.unconfirmed]
        rows.append(
            (
                name,
                " ".join(filter(None, (profile.manufacturer, profile.display_name))),
                _codes(profile),
                _fault_range(profile.faults),
                profile.max_words,
                "; ".join(notes),
            )
        )
    header = (
        "model (aliases)",
        "maker, series",
        "2103H",
        "fault table",
        "words a request",
        "notes",
    )
    return _table(header, rows)


def _register_range(register: Register) -> str:
    if not register.writable:
        return ""
    scale = 10**register.decimals
    low = "" if register.minimum is None else f"{register.minimum / scale:g}"
    high = register.maximum_from or (
        "" if register.maximum is None else f"{register.maximum / scale:g}"
    )
    return f"{low} ... {high}" if low or high else "any word"


def registers_markdown() -> str:
    """INVT's communication registers: address, access, unit and scale, the telemetry key MQTT
    publishes it as."""
    keys = {value.register.address: value.key for value in RUNNING_VALUES}
    rows = []
    for register in COMMUNICATION_REGISTERS:
        access = "R" * register.readable + "W" * register.writable
        scale = f"x{10**register.decimals}" if register.decimals else ""
        signed = "signed" if register.signed else ""
        telemetry = f"`{keys[register.address]}`" if register.address in keys else ""
        rows.append(
            (
                format_register(register.address),
                f"`{register.name}`",
                access,
                register.unit,
                " ".join(filter(None, (scale, signed))),
                _register_range(register),
                telemetry,
                register.description,
            )
        )
    header = ("address", "name", "access", "unit", "on the wire", "writes", "telemetry key", "")
    return _table(header, rows)


def faults_markdown(heading: str = "###") -> str:
    """Every fault list a model uses (one section per list, however many series share it):
    code, keypad short code, the manual's words."""
    lists: dict[tuple[tuple[int, tuple[str, str]], ...], list[DriveProfile]] = {}
    for profile in PROFILES.values():
        if profile.faults.entries:
            lists.setdefault(tuple(sorted(profile.faults.entries.items())), []).append(profile)
    out = []
    for entries, profiles in lists.items():
        name = profiles[0].faults.name
        out.append(f"{heading} {name[0].upper()}{name[1:]} fault table\n")
        used = ", ".join(
            f"`{profile.key}`" + ("" if profile.faults.confirmed else " (unconfirmed)")
            for profile in profiles
        )
        out.append(f"Used by {used}: codes {entries[0][0]}-{entries[-1][0]}.\n")
        rows = ((code, f"`{short}`" if short else "", words) for code, (short, words) in entries)
        out.append(_table(("code", "keypad", "description"), rows))
    return "\n".join(out)


def _setting(parameter: Parameter) -> str:
    parts = [f"{value}: {words}" for value, words in parameter.choices]
    parts += [parameter.hint] if parameter.hint else []
    parts += [f"**writing it {parameter.action}**"] if parameter.action else []
    parts += (
        [f"set by the factory: {parameter.factory}, never restored"] if parameter.factory else []
    )
    if parameter.reinitialises:
        parts.append("resets " + ", ".join(parameter.reinitialises))
    parts += [f"*{parameter.note}*"] if parameter.note else []
    return "; ".join(parts)


def parameter_rows(rows: Iterable[Parameter]) -> str:
    header = ("code", "name", "range", "default", "change", "values and notes")
    return _table(
        header,
        (
            (
                f"`{row.name}`",
                row.description,
                row.range_text(),
                row.shown_default() or "depends on model",
                CHANGE_MARKS["●" if row.read_only else "◎" if row.locked_while_running else "○"],
                _setting(row),
            )
            for row in rows
        ),
    )


def _series_of(table: str) -> Iterator[tuple[str, bool]]:
    """The series whose parameters take rows from `table`, each with whether confirmed."""
    for series, layers in sources()["series"].items():
        for layer in layers:
            if layer["table"] == table:
                yield series, bool(layer.get("confirmed", True))


def parameters_markdown(heading: str = "##") -> str:
    """Which tables make up each series' parameters, then every table with its sources and
    rows, group by group, as `data/parameter_sources.yaml` and the CSV files give them."""
    out = [f"{heading} Each series' parameters\n"]
    series_rows = []
    for series, layers in sources()["series"].items():
        taken = [
            f"`{layer['table']}`" + ("" if layer.get("confirmed", True) else " (unconfirmed)")
            for layer in layers
        ]
        table: ParameterTable = series_table(series)
        series_rows.append((f"`{series}`", ", then ".join(taken), len(table.rows)))
    out.append("The first table that has a code wins.\n")
    out.append(_table(("series", "tables, in order", "parameters"), series_rows))
    for name, described in sources()["tables"].items():
        out.append(f"{heading} Table `{name}`\n")
        users = ", ".join(
            f"`{series}`" + ("" if confirmed else " (unconfirmed)")
            for series, confirmed in _series_of(name)
        )
        out.append(f"{_cell(described['document'])}.\n")
        out.append(f"Used by: {users or 'no series'}.\n")
        rows = table_rows(name)
        groups: dict[str, list[Parameter]] = {}
        for row in rows:
            groups.setdefault(row.group, []).append(row)
        for group, members in groups.items():
            pages = described.get("groups", {}).get(group, "")
            out.append(f"{heading}# `{name}` {group}\n")
            if pages:
                out.append(f"Source: {_cell(pages)}.\n")
            out.append(parameter_rows(members))
    return "\n".join(out)
