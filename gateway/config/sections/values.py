"""How the file writes the plant's numbers: unit ids, identification words ("01F0H"), function
codes ("10H") and register ranges ("2000H-2001H", "P00.00-P00.15")."""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Annotated

from pydantic import BeforeValidator, Field, PlainSerializer, PlainValidator


@dataclass(frozen=True, slots=True)
class RegisterRange:
    """One entry of an access rule's `registers`: "2000H-2001H", "P00.00-P00.15", "2100H", 8192."""

    first: int
    last: int
    parameters: bool
    """Spelled as parameters (Pxx.yy): the range also covers their RAM-only addresses (8xxxH),
    which write the same parameters without the EEPROM."""

    @property
    def spans(self) -> tuple[tuple[int, int], ...]:
        if not self.parameters:
            return ((self.first, self.last),)
        from gateway.profile.addressing import RAM_BIT

        return (self.first, self.last), (self.first | RAM_BIT, self.last | RAM_BIT)

    @property
    def text(self) -> str:
        """As the file writes it ("2000H-2001H", "P00.00-P00.15", "2100H"): what a dump of the
        configuration says (the console's, `check-config --peer`'s), read back the same."""
        from gateway.profile.addressing import format_parameter, format_register

        spell = format_parameter if self.parameters else format_register
        ends = [self.first] if self.first == self.last else [self.first, self.last]
        return "-".join(map(spell, ends))


def _register_range(value: object) -> RegisterRange:
    from gateway.profile.addressing import is_parameter_register, parse_register

    if isinstance(value, RegisterRange):
        return value
    if isinstance(value, bool) or not isinstance(value, int | str):
        raise ValueError(f"{value!r}: write a register or a range, e.g. 2000H-2001H")
    if isinstance(value, int):
        if not 0 <= value <= 0xFFFF:
            raise ValueError(f"register {value} is outside 0..65535 (0000H..FFFFH)")
        return RegisterRange(value, value, False)
    ends = [end.strip() for end in value.split("-")]
    if len(ends) > 2 or not all(ends):
        raise ValueError(f"{value!r}: write one register or FIRST-LAST, e.g. 2000H-2001H")
    try:
        first, last = parse_register(ends[0]), parse_register(ends[-1])
    except ValueError as exc:
        raise ValueError(f"{value!r}: {exc}") from None
    if first > last:
        raise ValueError(f"{value!r}: the first register comes after the last")
    parameters = all(_PARAMETER_NAME.fullmatch(end) for end in ends)
    if parameters and not all(map(is_parameter_register, (first, last))):
        raise ValueError(f"{value!r} is not a parameter range")
    return RegisterRange(first, last, parameters)


_PARAMETER_NAME = re.compile(r"P\d{1,2}\.\d{1,2}", re.IGNORECASE)


def _function_code(value: object) -> object:
    """16, "10H" or "0x10" (function codes are usually written in hex)."""
    if isinstance(value, str):
        text = value.strip()
        try:
            if text[-1:] in "hH" and text[:-1]:
                return int(text[:-1], 16)
            if text.lower().startswith("0x"):
                return int(text, 16)
        except ValueError:
            pass
    return value


def _word(value: object) -> object:
    """0x01F0, "01F0H" or "0x01F0" (identification codes are written in hex)."""
    if isinstance(value, str):
        text = value.strip()
        try:
            if text[-1:] in "hH" and text[:-1]:
                return int(text[:-1], 16)
            return int(text, 0)
        except ValueError:
            pass
    return value


UnitId = Annotated[int, Field(ge=0, le=255)]
Word = Annotated[int, BeforeValidator(_word), Field(ge=0, le=0xFFFF)]
FunctionCode = Annotated[int, BeforeValidator(_function_code), Field(ge=1, le=127)]
Registers = Annotated[
    RegisterRange, PlainValidator(_register_range), PlainSerializer(lambda r: r.text)
]
