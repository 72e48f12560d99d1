"""The point resolver: what a person types to name a value of an INVT drive, and how its raw
word reads. `Point` is what every profile's `resolve` answers; this module's `resolve` is
INVT's (`InvtProfile.resolve`), and the one the field tools use for a drive of no known model.

Accepted spellings, tried in this order:
- `P00.11`: a function parameter (scale, unit and meaning from the profile's parameter table);
- a register name from the profile (`frequency_setpoint`, `state_word_1`);
- a telemetry key, with or without its unit (`output_frequency_hz`, `output_frequency`);
- an address: `2100H`, `0x2100`, `8448` (named when the profile knows it, raw otherwise).

A value is shown scaled with its unit and, for the words that are codes, decoded: state word 1
("stopped"), state word 2, fault codes ("STo: maladjustment"), the identification ("GD350").
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from enum import Enum
from typing import TYPE_CHECKING, Protocol

from gateway.profile import words
from gateway.profile.addressing import (
    format_parameter,
    format_register,
    is_parameter_register,
    parse_register,
)
from gateway.profile.parameters import FAULT_HISTORY, Parameter, parameter_at
from gateway.profile.registers import RUNNING_VALUES, Register, register_at, register_by_name
from gateway.profile.states import CONTROL_COMMANDS, control_command

if TYPE_CHECKING:
    from gateway.profile.parameter_tables import ParameterTable

_PARAMETER = re.compile(r"P\d{1,2}\.\d{1,2}", re.IGNORECASE)
_UNIT_SUFFIXES = ("_hz", "_v", "_a", "_rpm", "_pct")
_COMMAND_NAMES = {int(command): name for name, command in CONTROL_COMMANDS.items()}


class Profile(Protocol):
    """What a point reads of a drive's profile (any `DriveProfile`): typed here rather than
    importing the protocol, which names `Point`."""

    @property
    def key(self) -> str: ...

    @property
    def parameter_table(self) -> ParameterTable: ...


class Meaning(Enum):
    NUMBER = "number"
    STATE_WORD_1 = "state_word_1"
    STATE_WORD_2 = "state_word_2"
    FAULT = "fault"
    IDENTIFICATION = "identification"
    CONTROL_WORD = "control_word"


@dataclass(frozen=True)
class Point:
    label: str
    """How it is shown: "P00.11", "output_frequency", "2100H"."""
    address: int
    description: str = ""
    decimals: int = 0
    unit: str = ""
    signed: bool = False
    meaning: Meaning = Meaning.NUMBER
    choices: tuple[tuple[int, str], ...] = ()
    """The manual's words for a value (a parameter of the drive's series table)."""
    minimum: int | None = None
    maximum: int | None = None
    """The manual's range, as numbers of the register's scale (signed where the range is):
    checked before a write goes on the wire. None: no range known."""
    bounded_by: tuple[str | None, str | None] = (None, None)
    """Parameters whose value bounds this one at run time (P00.04 within P00.05..P00.03): the
    drive checks those; the manual's outer range is checked here."""
    borrowed_for: str = ""
    """The series (`gd350`) whose table took this row from another series' manual, unconfirmed:
    its range is then left to the drive (no `minimum`/`maximum` here), and a refusal says so."""

    @property
    def borrowed_note(self) -> str:
        """What a drive's refusal of a write adds: "P01.00's range is another series' (the
        table is borrowed, unconfirmed for gd350): the drive checked it"; "" otherwise."""
        if not self.borrowed_for:
            return ""
        return (
            f"{self.label}'s range is another series' (the table is borrowed, unconfirmed for "
            f"{self.borrowed_for}): the drive checked it"
        )

    @property
    def where(self) -> str:
        return format_register(self.address)

    @property
    def depends_on_series(self) -> bool:
        """Whether the words for a value need the drive's series (2101H bit 0, fault names)."""
        return self.meaning in (Meaning.STATE_WORD_2, Meaning.FAULT)

    def show(self, raw: int, profile: Profile | None) -> str:
        """ "10.0 s", "3 (stopped)", "35 (STo: maladjustment)", "0106H (GD20)", "5 (stop)".

        The status words are shown by their decoders in `gateway.profile.words`, for
        `profile`'s series (None: not known, so 2101H bit 0 is left undecided)."""
        raw &= 0xFFFF
        # An INVT series decides 2101H bit 0 and the fault names; another maker's doesn't.
        series = profile if isinstance(profile, words.Series) else None
        match self.meaning:
            case Meaning.STATE_WORD_1:
                return words.show_state_word_1(raw)
            case Meaning.STATE_WORD_2:
                return words.show_state_word_2(series, raw)
            case Meaning.FAULT:
                return words.show_fault(series, raw)
            case Meaning.IDENTIFICATION:
                return words.show_identification(raw)
            case Meaning.CONTROL_WORD if raw in _COMMAND_NAMES:
                return f"{raw} ({_COMMAND_NAMES[raw]})"
        value = raw - 0x10000 if self.signed and raw & 0x8000 else raw
        number = f"{value / 10**self.decimals:.{self.decimals}f}" if self.decimals else str(value)
        shown = f"{number} {self.unit}".rstrip()
        words_for = next((text for choice, text in self.choices if choice == raw), None)
        return f"{shown} ({words_for})" if words_for else shown

    def encode(self, text: str) -> int:
        """The raw word for a value as a person writes it: "10.0", "12.5 s", "25Hz" (the
        point's own unit), "-5", "0x0064", "stop", or one of the manual's words for a choice
        ("keypad"). Refused before the wire, saying why: a value finer than the register's
        resolution (never rounded silently), outside the manual's range (given with its unit),
        or not a number."""
        text = text.strip()
        if self.meaning is Meaning.CONTROL_WORD and not _is_number(text):
            return int(control_command(text))
        if text.lower().startswith("0x"):
            return _word(int(text, 16), text)
        number = self._without_unit(text)
        chosen = self._choice_named(number)
        if chosen is not None:
            return self._in_range(chosen, text) & 0xFFFF
        try:
            value = float(number)
        except ValueError:
            raise ValueError(self._not_a_number(text)) from None
        scaled = value * float(10**self.decimals)
        if not math.isfinite(scaled):  # 1e308, inf, nan: round() would raise OverflowError
            raise ValueError(f"{self.label} = {text} does not fit in one register")
        raw = round(scaled)
        if abs(scaled - raw) > 1e-6 * max(1.0, abs(scaled)):  # finer than the register holds
            below, above = (raw if raw < scaled else raw - 1), (raw if raw > scaled else raw + 1)
            raise ValueError(
                f"{self.label} takes steps of {self._scaled(1)}: {text} would not be written as "
                f"given (the nearest are {self._scaled(below)} and {self._scaled(above)})"
                if self.decimals
                else f"{self.label} takes whole numbers: {text} can't be written"
            )
        self._in_range(raw, text)  # the manual's range first: it says more than the word's
        low, high = (-0x8000, 0x7FFF) if self.signed else (0, 0xFFFF)
        if not low <= raw <= high:
            scale = f" (x{10**self.decimals})" if self.decimals else ""
            raise ValueError(f"{self.label} = {text}{scale} does not fit in one register")
        return raw & 0xFFFF

    def _scaled(self, raw: int) -> str:
        number = f"{raw / 10**self.decimals:.{self.decimals}f}" if self.decimals else str(raw)
        return f"{number} {self.unit}".rstrip()

    def _without_unit(self, text: str) -> str:
        """ "25Hz", "12.5 s" → "25", "12.5": the point's own unit, letter case aside."""
        unit = self.unit.strip()
        if unit and text.casefold().endswith(unit.casefold()):
            return text[: -len(unit)].rstrip()
        return text

    def _choice_named(self, text: str) -> int | None:
        """The value whose manual words are `text` (or begin with it, when only one does)."""
        if not self.choices or _is_number(text):
            return None
        wanted = text.casefold()
        exact = [value for value, words in self.choices if words.casefold() == wanted]
        if exact:
            return exact[0]
        begun = [value for value, words in self.choices if words.casefold().startswith(wanted)]
        return begun[0] if len(begun) == 1 else None

    def _not_a_number(self, text: str) -> str:
        said = f"{self.label}: {text!r} is not a number"
        if self.unit:
            said += f" (in {self.unit}: 10, 10 {self.unit})"
        if self.choices:
            said += "; or one of: " + ", ".join(f"{v} {words}" for v, words in self.choices)
        return said

    def _in_range(self, raw: int, text: str) -> int:
        low, high = self.minimum, self.maximum
        if (low is not None and raw < low) or (high is not None and raw > high):
            bounds = f"{self._scaled(low or 0).split()[0]}..{self._scaled(high or 0x7FFF)}"
            lower, upper = self.bounded_by
            if lower and upper:
                at_run_time = f"; the drive also keeps it within {lower}..{upper}"
            elif lower or upper:
                at_run_time = f"; the drive also keeps it at or {'above' if lower else 'below'} "
                at_run_time += lower or upper or ""
            else:
                at_run_time = ""
            raise ValueError(f"{self.label} = {text} is outside {bounds}{at_run_time}")
        return raw


def resolve(text: str) -> Point:
    """The point `text` names; ValueError saying which spellings work."""
    spelled = text.strip()
    if _PARAMETER.fullmatch(spelled):
        address = parse_register(spelled)
        return _parameter_point(format_parameter(address), address)
    named = _named_register(spelled)
    if named is not None:
        return named
    try:
        address = parse_register(spelled)
    except ValueError:
        raise ValueError(
            f"{text!r} is not a known name: use Pxx.yy (P00.11), a register (2100H, 0x2100) "
            f"or a name such as frequency_setpoint, state_word_1, output_frequency"
        ) from None
    register = register_at(address)
    if register is not None:
        return _register_point(register, format_register(address))
    if is_parameter_register(address) and parameter_at(address & 0x7FFF) is not None:
        return _parameter_point(format_parameter(address), address)
    return Point(format_register(address), address, "not in the profile: shown raw")


def _named_register(name: str) -> Point | None:
    key = name.lower()
    try:
        return _register_point(register_by_name(key), key)
    except ValueError:
        pass
    for running in RUNNING_VALUES:
        bare = _strip_unit(running.key)
        if key in (running.key, bare):
            return _register_point(running.register, name)
    return None


def _strip_unit(key: str) -> str:
    for suffix in _UNIT_SUFFIXES:
        if key.endswith(suffix):
            return key.removesuffix(suffix)
    return key


def _register_point(register: Register, label: str) -> Point:
    meaning = {
        "state_word_1": Meaning.STATE_WORD_1,
        "state_word_2": Meaning.STATE_WORD_2,
        "fault_code": Meaning.FAULT,
        "fault_code_5000": Meaning.FAULT,
        "identification": Meaning.IDENTIFICATION,
        "identification_mirror": Meaning.IDENTIFICATION,
        "control_word": Meaning.CONTROL_WORD,
    }.get(register.name, Meaning.NUMBER)
    description = register.name.replace("_", " ")
    if register.description:
        description += f": {register.description}"
    return Point(
        label,
        register.address,
        description,
        register.decimals,
        register.unit,
        register.signed,
        meaning,
    )


def for_series(point: Point, profile: Profile | None) -> Point:
    """A parameter as the drive's series table describes and scales it (the common table, which
    `resolve` uses, knows 25 codes); any other point, or without a series, as it is."""
    if profile is None or not point.label.startswith("P"):
        return point
    row = profile.parameter_table.at(point.address & 0x7FFF)
    if row is None:
        return point
    meaning = Meaning.FAULT if row.name in FAULT_HISTORY else Meaning.NUMBER
    # Another series' range can't be held against this drive: only the drive can check it.
    confirmed = row.confirmed
    return Point(
        point.label,
        point.address,
        row.description,
        row.decimals,
        row.unit,
        row.signed,
        meaning,
        row.choices,
        row.minimum if confirmed else None,
        row.maximum if confirmed else None,
        (row.minimum_from, row.maximum_from),
        "" if confirmed else profile.key,
    )


def beyond_common_table(point: Point) -> bool:
    """A parameter the common table doesn't know: only the drive's series can scale it."""
    return point.label.startswith("P") and parameter_at(point.address & 0x7FFF) is None


def _parameter_point(label: str, address: int) -> Point:
    known: Parameter | None = parameter_at(address & 0x7FFF)
    if known is None:
        return Point(label, address, "not in the profile's parameter table: shown raw")
    meaning = Meaning.FAULT if known.name in FAULT_HISTORY else Meaning.NUMBER
    return Point(
        label,
        address,
        known.description,
        known.decimals,
        known.unit,
        known.signed,
        meaning,
        known.choices,
        known.minimum,
        known.maximum,
        (known.minimum_from, known.maximum_from),
    )


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return text.lower().startswith("0x")
    return True


def _word(value: int, text: str) -> int:
    if not 0 <= value <= 0xFFFF:
        raise ValueError(f"{text} does not fit in one register (0000H...FFFFH)")
    return value
