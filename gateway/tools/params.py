"""Parameter sets: a drive's writable parameters saved to YAML, compared, written back.

For commissioning and for replacing a failed drive: `backup` reads every writable parameter the
profile knows, group by group; `diff` compares a file with a drive; `restore` writes only what
differs. The file is meant to be read and edited by people:

    model: gd350a
    series: GD350A
    identification: 01A2H
    address: 1
    saved: 2024-05-01T12:00:00Z
    parameters:
      P00:
        P00.03: {value: 50.0, unit: Hz, description: max. output frequency}
        P00.11: {value: 10.0, unit: s, description: acceleration time 1}

Left out of a backup: read-only parameters (the fault history, the monitoring group P17), the
codes that set something off rather than store a setting (P00.15 autotuning, P00.18 restore
the defaults, P07.01 parameter copy: `Parameter.action`), and the line's own settings
P14.00-P14.02 (address, baud, data format): written to another drive they would take it off the
line. Where the series' table is another series' (unconfirmed, see `profile.parameter_tables`),
a code the drive answers with exception 02H is passed over and listed under `absent`, and the
file lists the `unconfirmed` groups; their values are kept exactly but their ranges are not
held against the file.

A restore refuses while the drive runs (state word 1 says running or pre-exciting): the
manual's "◎" codes can't change then (exception 08H), and a drive that runs on half its new
settings is not what a technician restoring a backup wants. It skips, with the reason, a
read-only parameter and one the manual says is set at the factory (the bar codes P07.21-P07.26:
`Parameter.factory`); it stops at the first exception the drive answers, naming the parameter.
Writes are ordered: the motor's type and rated power first (the Goodrive200A manual, page 46:
"Resetting the rated motor power (P02.01) will initialize P02.02-P02.10", which are written
again after it), then each bound (P00.03, max. frequency) before the parameters it bounds need
it, the communication group last. Each write is read back at once (`check_written`), and the
whole file once more at the end, where what a later write re-initialised would show.
"""

from __future__ import annotations

import struct
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import yaml

from gateway.errors import FieldError
from gateway.modbus.functions import READ_HOLDING_REGISTERS, WRITE_SINGLE_REGISTER
from gateway.profile import DriveProfile, Parameter, get_profile, parse_parameter
from gateway.profile.addressing import ram_address
from gateway.profile.exception_codes import ILLEGAL_DATA_ADDRESS
from gateway.profile.invt import IDENTIFICATION, STATE_WORD_1, describe_identification
from gateway.profile.parameter_tables import ParameterTable
from gateway.profile.states import RunState
from gateway.profile.words import show_state_word_1
from gateway.tools.access import ask
from gateway.tools.advice import GARBLED
from gateway.tools.masters import Master

LINE_SETTINGS = frozenset({"P14.00", "P14.01", "P14.02"})
"""Address, baud rate, data format: the line's, not the drive's."""
WRITTEN_FIRST = ("P02.00", "P02.01")
"""Motor type and rated power: writing the rated power re-initialises the rest of the motor's
rated and model data (`Parameter.reinitialises`), so they go before them."""
WRITTEN_LAST = "P14"
"""The communication group: its response mode and protocol settings (P14.06: no reply to
writes, another address map) would cut a restore short if written before the rest."""
RUNNING_STATES = frozenset(
    {RunState.RUNNING_FORWARD, RunState.RUNNING_REVERSE, RunState.PRE_EXCITING}
)

Progress = Callable[[str], None]
"""Called with a parameter's name as each one is read or written."""


def _nothing(name: str) -> None:
    return None


def saved_parameters(profile: DriveProfile) -> list[Parameter]:
    """What a backup holds: every writable parameter the profile knows but the line settings,
    the factory's and the codes that set something off (P00.18, restore the defaults)."""
    return [p for p in profile.parameters if not skip_reason(p)]


# ------------------------------------------------------------------------------ the drive


def read_word(master: Master, address: int, register: int, what: str) -> int:
    return read_words(master, address, register, 1, what)[0]


def read_words(master: Master, address: int, start: int, count: int, what: str) -> list[int]:
    pdu = struct.pack(">BHH", READ_HOLDING_REGISTERS, start, count)
    reply = ask(master, address, pdu, what)
    if len(reply) != 2 + 2 * count or reply[1] != 2 * count:
        raise FieldError(f"{what}: unexpected reply {reply.hex(' ')}", GARBLED)
    return list(struct.unpack(f">{count}H", reply[2:]))


def identify(master: Master, address: int) -> int:
    return read_word(master, address, IDENTIFICATION, f"reading 2103H at address {address}")


def profile_of(master: Master, address: int, model: str | None) -> tuple[DriveProfile, int]:
    """The drive's profile: `model` when given, else the one its 2103H code names."""
    code = identify(master, address)
    if model is not None:
        return get_profile(model), code
    from gateway.profile import profiles_for_identification

    profiles = profiles_for_identification(code)
    if len(profiles) != 1:
        raise FieldError(
            f"the drive at address {address} answers 2103H = {code:04X}H "
            f"({describe_identification(code)}): say which series it is with --model"
        )
    return profiles[0], code


def read_parameters(
    master: Master,
    address: int,
    specs: list[Parameter],
    progress: Progress = _nothing,
    *,
    max_words: int = 16,
    absent: list[str] | None = None,
) -> dict[str, int]:
    """Raw values by name, read in runs of contiguous registers (at most `max_words` each).

    With `absent`, an unconfirmed parameter the drive answers with exception 02H (no such
    address: the table is another series') is named there and left out, not an error."""
    values: dict[str, int] = {}
    for run in _runs(specs, max_words):
        first = run[0]
        what = f"reading {first.name}-{run[-1].name} at address {address}"
        try:
            words: list[int | None] = list(
                read_words(master, address, first.address, len(run), what)
            )
        except FieldError:
            if len(run) == 1 and not _may_be_absent(run[0], absent):
                raise
            # One word at a time, so the error names the parameter the drive refuses.
            words = [_read_one(master, address, spec, absent) for spec in run]
        for spec, word in zip(run, words, strict=True):
            if word is not None:
                values[spec.name] = word
            progress(spec.name)
    return values


def _may_be_absent(spec: Parameter, absent: list[str] | None) -> bool:
    return absent is not None and not spec.confirmed


def _read_one(
    master: Master, address: int, spec: Parameter, absent: list[str] | None
) -> int | None:
    try:
        return read_word(master, address, spec.address, f"reading {spec.name} at {address}")
    except FieldError as exc:
        if exc.exception_code != ILLEGAL_DATA_ADDRESS or not _may_be_absent(spec, absent):
            raise
        assert absent is not None
        absent.append(spec.name)
        return None


def _runs(specs: list[Parameter], max_words: int = 16) -> list[list[Parameter]]:
    runs: list[list[Parameter]] = []
    for spec in specs:
        last = runs[-1] if runs else None
        if last and spec.address == last[-1].address + 1 and len(last) < max_words:
            last.append(spec)
        else:
            runs.append([spec])
    return runs


def is_running(master: Master, address: int) -> bool:
    return running_state(master, address) is not None


def running_state(master: Master, address: int) -> str | None:
    """ "1 (running_forward)" when the drive runs or pre-excites (state word 1, decoded as
    every surface decodes it), None when it does not."""
    state = read_word(master, address, STATE_WORD_1, f"reading 2100H at address {address}")
    return show_state_word_1(state) if state in RUNNING_STATES else None


def refuse_if_running(master: Master, address: int) -> None:
    """A restore's first check: a running drive is stopped by its operator, not by us."""
    state = running_state(master, address)
    if state is not None:
        raise FieldError(
            f"the drive at address {address} runs (2100H = {state}): stop it before a "
            f"restore; nothing was written",
            ("stop the drive (keypad, terminal or `invt-gateway write 2000H=stop`), then restore",),
        )


def write_parameter(master: Master, address: int, spec: Parameter, raw: int, ram: bool) -> None:
    register = ram_address(spec.address) if ram else spec.address
    where = f"{register:04X}H, RAM only" if ram else f"{register:04X}H"
    what = f"writing {spec.name} ({where}) = {show(spec, raw)} at address {address}"
    pdu = struct.pack(">BHH", WRITE_SINGLE_REGISTER, register, raw)
    reply = ask(master, address, pdu, what)
    if reply != pdu:
        raise FieldError(f"{what}: the echo {reply.hex(' ')} differs from the request", GARBLED)


def check_written(master: Master, address: int, spec: Parameter, raw: int) -> int:
    """What the drive holds at `spec` just after `raw` was written there (a drive may round or
    clamp a value and still echo the request)."""
    return read_word(master, address, spec.address, f"reading back {spec.name} at {address}")


# ------------------------------------------------------------------------------ the file


@dataclass(frozen=True)
class ParameterSet:
    profile: DriveProfile
    values: dict[str, int]
    """Raw values by parameter name."""

    def specs(self) -> list[Parameter]:
        known = {p.name: p for p in self.profile.parameters}
        return [known[name] for name in self.values]


def engineering(spec: Parameter, raw: int) -> float | int:
    number = spec.number(raw)
    return number / 10**spec.decimals if spec.decimals else number


def show(spec: Parameter, raw: int) -> str:
    """ "50.00 Hz", "0x01FF", "2 (SVPWM (V/F) control)": `Parameter.show`."""
    return spec.show(raw)


def show_number(spec: Parameter, number: int) -> str:
    """A bound in the range's units ("-300.0 %")."""
    return show(spec, spec.word(number)).split(" (")[0]


def to_yaml(
    parameters: ParameterSet,
    identification: int,
    address: int,
    saved_at: float | None = None,
    absent: Iterable[str] = (),
) -> str:
    """The file: values in the manual's units, each with its unit, name and the manual's words
    for it; `unconfirmed` lists the groups whose table is another series', `absent` the codes
    of that table this drive does not have."""
    groups: dict[str, dict[str, dict[str, Any]]] = {}
    for spec in parameters.specs():
        raw = parameters.values[spec.name]
        entry: dict[str, Any] = {"value": engineering(spec, raw)}
        if spec.hexadecimal and not spec.decimals:
            entry["hex"] = f"0x{raw:04X}"
        if spec.unit:
            entry["unit"] = spec.unit
        entry["description"] = spec.description
        if (choice := spec.choice(raw)) is not None:
            entry["choice"] = choice
        groups.setdefault(spec.group, {})[spec.name] = entry
    moment = time.gmtime(time.time() if saved_at is None else saved_at)
    document: dict[str, Any] = {
        "model": parameters.profile.key,
        "series": parameters.profile.display_name,
        "identification": f"{identification:04X}H",
        "address": address,
        "saved": time.strftime("%Y-%m-%dT%H:%M:%SZ", moment),
    }
    unconfirmed = sorted({spec.group for spec in parameters.specs() if not spec.confirmed})
    if unconfirmed:
        document["unconfirmed"] = unconfirmed
    missing = list(absent)
    if missing:
        document["absent"] = missing
    document["parameters"] = groups
    return yaml.safe_dump(
        document, sort_keys=False, allow_unicode=True, width=120, default_flow_style=None
    )


def from_yaml(text: str, source: str) -> ParameterSet:
    """A parameter file, checked whole before anything is written: model, names, ranges."""
    try:
        document = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ValueError(f"{source}: not valid YAML: {exc}") from None
    if not isinstance(document, dict) or not isinstance(document.get("parameters"), dict):
        raise ValueError(f"{source}: not a parameter file (no 'model' and 'parameters')")
    try:
        profile = get_profile(str(document.get("model")))
    except ValueError as exc:
        raise ValueError(f"{source}: model: {exc}") from None
    known = {p.name: p for p in profile.parameters}
    values: dict[str, int] = {}
    for group, entries in document["parameters"].items():
        if not isinstance(entries, dict):
            raise ValueError(f"{source}: parameters.{group}: expected Pxx.yy entries")
        for name, entry in entries.items():
            key = f"parameters.{group}.{name}"
            spec = known.get(str(name))
            if spec is None:
                raise ValueError(f"{source}: {key}: not a parameter of {profile.display_name}")
            value = entry.get("value") if isinstance(entry, dict) else entry
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ValueError(f"{source}: {key}.value: expected a number, got {value!r}")
            shown_hex = entry.get("hex") if isinstance(entry, dict) else None
            if shown_hex is not None and str(shown_hex).lower() != f"0x{int(value):04x}":
                raise ValueError(
                    f"{source}: {key}.hex: {shown_hex} is not value {value}: "
                    f"edit value (hex only shows it)"
                )
            number = round(value * 10**spec.decimals)
            # An unconfirmed range is another series': only the register's width holds.
            low, high = (spec.minimum, spec.maximum) if spec.confirmed else (-0x8000, 0xFFFF)
            if not low <= number <= high:
                shown = f"{show_number(spec, low)} ... {show_number(spec, high)}"
                raise ValueError(f"{source}: {key}.value: {value} is outside {shown}")
            values[spec.name] = spec.word(number)
    return ParameterSet(profile, values)


# ------------------------------------------------------------------------------ comparing


@dataclass(frozen=True)
class Difference:
    spec: Parameter
    drive: int
    file: int

    def line(self) -> str:
        return (
            f"{self.spec.name}  {self.spec.description}: drive {show(self.spec, self.drive)}, "
            f"file {show(self.spec, self.file)}"
        )


def differences(wanted: ParameterSet, actual: Mapping[str, int]) -> list[Difference]:
    return [
        Difference(spec, actual[spec.name], wanted.values[spec.name])
        for spec in wanted.specs()
        if actual[spec.name] != wanted.values[spec.name]
    ]


def skip_reason(spec: Parameter) -> str:
    """Why a restore never writes `spec`, or "" when it may."""
    if spec.factory:
        return f"set at the factory: {spec.factory}"
    if spec.read_only:
        return "read-only"
    if spec.action:
        return f"a command, not a setting: it {spec.action}"
    if spec.name in LINE_SETTINGS:
        return "the line's own setting: set it on the keypad"
    return ""


@dataclass(frozen=True)
class Skipped:
    difference: Difference
    reason: str


def plan(
    changes: Iterable[Difference],
    actual: Mapping[str, int],
    table: ParameterTable | None = None,
) -> tuple[list[Difference], list[Skipped]]:
    """What to write to a stopped drive, in an order it accepts, and what to skip and why."""
    writes: list[Difference] = []
    skipped: list[Skipped] = []
    for change in changes:
        reason = skip_reason(change.spec)
        if reason:
            skipped.append(Skipped(change, reason))
        else:
            writes.append(change)
    writes += _rewritten(writes, skipped, actual, table)
    first = [w for name in WRITTEN_FIRST for w in writes if w.spec.name == name]
    last = [w for w in writes if w.spec.group == WRITTEN_LAST and w not in first]
    rest = [w for w in writes if w not in first and w not in last]
    return first + _ordered(rest, actual, table) + last, skipped


def _rewritten(
    writes: list[Difference],
    skipped: list[Skipped],
    actual: Mapping[str, int],
    table: ParameterTable | None,
) -> list[Difference]:
    """The file's parameters a planned write re-initialises on the drive (P02.01 resets
    P02.02-P02.10: `Parameter.reinitialises`), to be written again after it, from the file,
    where the drive held the file's value too."""
    planned = {w.spec.name for w in writes} | {skip.difference.spec.name for skip in skipped}
    again: list[Difference] = []
    for write in writes:
        for name in write.spec.reinitialises:
            spec = _spec_by_name(name, table)
            if spec is not None and name in actual and name not in planned:
                again.append(Difference(spec, actual[name], actual[name]))
                planned.add(name)
    return again


def _ordered(
    writes: list[Difference], actual: Mapping[str, int], table: ParameterTable | None
) -> list[Difference]:
    """Each write when the values its range depends on (P00.04 within P00.05 ... P00.03) let
    it through; what never fits keeps its place at the end, for the drive to refuse by name."""
    state = dict(actual)
    pending = list(writes)
    ordered: list[Difference] = []
    while pending:
        fits = next((w for w in pending if _fits(w, state, table)), None)
        if fits is None:
            return ordered + pending
        pending.remove(fits)
        ordered.append(fits)
        state[fits.spec.name] = fits.file
    return ordered


def _fits(write: Difference, state: Mapping[str, int], table: ParameterTable | None) -> bool:
    spec = write.spec
    wanted = spec.number(write.file)
    low = _bound(spec.minimum_from, state, table, spec.minimum)
    high = _bound(spec.maximum_from, state, table, spec.maximum)
    if not low <= wanted <= high:
        return False
    # ... and it must not push a parameter it bounds out of its own range.
    for other, value in state.items():
        spec_other = _spec_by_name(other, table)
        if spec_other is None:
            continue
        if spec_other.maximum_from == spec.name and spec_other.number(value) > wanted:
            return False
        if spec_other.minimum_from == spec.name and spec_other.number(value) < wanted:
            return False
    return True


def _bound(
    name: str | None, state: Mapping[str, int], table: ParameterTable | None, fixed: int
) -> int:
    """A range bound: the named parameter's value when it is known, else the fixed bound."""
    if name is None or name not in state:
        return fixed
    spec = _spec_by_name(name, table)
    return spec.number(state[name]) if spec is not None else state[name]


def _spec_by_name(name: str, table: ParameterTable | None) -> Parameter | None:
    if table is not None:
        return table.named(name)
    from gateway.profile.parameters import parameter_at

    try:
        return parameter_at(parse_parameter(name))
    except ValueError:
        return None
