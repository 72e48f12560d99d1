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

Left out of a backup: read-only parameters (the fault history) and the line's own settings
P14.00-P14.02 (address, baud, data format): written to another drive they would take it off the
line. A restore skips, with the reason, a read-only parameter and one that can't change while
the drive runs (when it runs); it stops at the first exception the drive answers, naming the
parameter. Writes are ordered so that a bound (P00.03, max. frequency) is moved before the
parameters it bounds need it.
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
from gateway.profile.invt import IDENTIFICATION, STATE_WORD_1, describe_identification
from gateway.profile.parameters import parameter_at
from gateway.profile.states import RunState
from gateway.tools.access import ask
from gateway.tools.advice import GARBLED
from gateway.tools.masters import Master

LINE_SETTINGS = frozenset({"P14.00", "P14.01", "P14.02"})
"""Address, baud rate, data format: the line's, not the drive's."""
RUNNING_STATES = frozenset(
    {RunState.RUNNING_FORWARD, RunState.RUNNING_REVERSE, RunState.PRE_EXCITING}
)

Progress = Callable[[str], None]
"""Called with a parameter's name as each one is read or written."""


def _nothing(name: str) -> None:
    return None


def saved_parameters(profile: DriveProfile) -> list[Parameter]:
    """What a backup holds: every writable parameter the profile knows but the line settings."""
    return [p for p in profile.parameters if not p.read_only and p.name not in LINE_SETTINGS]


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
    master: Master, address: int, specs: list[Parameter], progress: Progress = _nothing
) -> dict[str, int]:
    """Raw values by name, read in runs of contiguous registers (at most 16 words each)."""
    values: dict[str, int] = {}
    for run in _runs(specs):
        first = run[0]
        what = f"reading {first.name}-{run[-1].name} at address {address}"
        try:
            words = read_words(master, address, first.address, len(run), what)
        except FieldError:
            if len(run) == 1:
                raise
            # One word at a time, so the error names the parameter the drive refuses.
            words = [
                read_word(master, address, spec.address, f"reading {spec.name} at {address}")
                for spec in run
            ]
        for spec, word in zip(run, words, strict=True):
            values[spec.name] = word
            progress(spec.name)
    return values


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
    state = read_word(master, address, STATE_WORD_1, f"reading 2100H at address {address}")
    return state in RUNNING_STATES


def write_parameter(master: Master, address: int, spec: Parameter, raw: int, ram: bool) -> None:
    register = ram_address(spec.address) if ram else spec.address
    where = f"{register:04X}H, RAM only" if ram else f"{register:04X}H"
    what = f"writing {spec.name} ({where}) = {show(spec, raw)} at address {address}"
    pdu = struct.pack(">BHH", WRITE_SINGLE_REGISTER, register, raw)
    reply = ask(master, address, pdu, what)
    if reply != pdu:
        raise FieldError(f"{what}: the echo {reply.hex(' ')} differs from the request", GARBLED)


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
    return raw / 10**spec.decimals if spec.decimals else raw


def show(spec: Parameter, raw: int) -> str:
    value = f"{raw / 10**spec.decimals:.{spec.decimals}f}" if spec.decimals else str(raw)
    return f"{value} {spec.unit}".rstrip()


def to_yaml(
    parameters: ParameterSet, identification: int, address: int, saved_at: float | None = None
) -> str:
    groups: dict[str, dict[str, dict[str, Any]]] = {}
    for spec in parameters.specs():
        entry: dict[str, Any] = {"value": engineering(spec, parameters.values[spec.name])}
        if spec.unit:
            entry["unit"] = spec.unit
        entry["description"] = spec.description
        groups.setdefault(spec.name.split(".")[0], {})[spec.name] = entry
    moment = time.gmtime(time.time() if saved_at is None else saved_at)
    document = {
        "model": parameters.profile.key,
        "series": parameters.profile.display_name,
        "identification": f"{identification:04X}H",
        "address": address,
        "saved": time.strftime("%Y-%m-%dT%H:%M:%SZ", moment),
        "parameters": groups,
    }
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
            raw = round(value * 10**spec.decimals)
            if not spec.minimum <= raw <= spec.maximum:
                low, high = show(spec, spec.minimum), show(spec, spec.maximum)
                raise ValueError(f"{source}: {key}.value: {value} is outside {low} ... {high}")
            values[spec.name] = raw
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


@dataclass(frozen=True)
class Skipped:
    difference: Difference
    reason: str


def plan(
    changes: Iterable[Difference], actual: Mapping[str, int], running: bool
) -> tuple[list[Difference], list[Skipped]]:
    """What to write, in an order the drive accepts, and what to skip and why."""
    writes: list[Difference] = []
    skipped: list[Skipped] = []
    for change in changes:
        if change.spec.read_only:
            skipped.append(Skipped(change, "read-only"))
        elif change.spec.name in LINE_SETTINGS:
            skipped.append(Skipped(change, "the line's own setting: set it on the keypad"))
        elif change.spec.locked_while_running and running:
            skipped.append(Skipped(change, "can't change while the drive runs: stop it first"))
        else:
            writes.append(change)
    return _ordered(writes, actual), skipped


def _ordered(writes: list[Difference], actual: Mapping[str, int]) -> list[Difference]:
    """Each write when the values its range depends on (P00.04 within P00.05 ... P00.03) let
    it through; what never fits keeps its place at the end, for the drive to refuse by name."""
    state = dict(actual)
    pending = list(writes)
    ordered: list[Difference] = []
    while pending:
        fits = next((w for w in pending if _fits(w, state)), None)
        if fits is None:
            return ordered + pending
        pending.remove(fits)
        ordered.append(fits)
        state[fits.spec.name] = fits.file
    return ordered


def _fits(write: Difference, state: Mapping[str, int]) -> bool:
    spec = write.spec
    low = state.get(spec.minimum_from, spec.minimum) if spec.minimum_from else spec.minimum
    high = state.get(spec.maximum_from, spec.maximum) if spec.maximum_from else spec.maximum
    if not low <= write.file <= high:
        return False
    # ... and it must not push a parameter it bounds out of its own range.
    for other, value in state.items():
        spec_other = _spec_by_name(other)
        if spec_other is None:
            continue
        if spec_other.maximum_from == spec.name and value > write.file:
            return False
        if spec_other.minimum_from == spec.name and value < write.file:
            return False
    return True


def _spec_by_name(name: str) -> Parameter | None:
    try:
        return parameter_at(parse_parameter(name))
    except ValueError:
        return None
