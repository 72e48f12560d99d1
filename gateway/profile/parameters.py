"""A function parameter (Pxx.yy) as described: decimals, range, default, marks, the manual's words.

`PARAMETERS` is the common table: 25 codes for remote control that every series' table starts
with but the Goodrive200A's, whose manual was read whole (`parameter_tables` loads each series'
table from `data/`); `read`, `write` and the MQTT bridge scale by it when the series is not
known. Its ranges and factory defaults follow the Goodrive manuals; "depends on model" defaults
(P00.11, P00.12, P08.07, P08.08) are given a typical 10.0 s for a simulated drive to start
with (`default_known` False: the console doesn't call it the factory's). A range bound may be
another parameter's value (P00.04, the upper limit, lies within P00.05 ... P00.03):
`minimum_from` and `maximum_from`.

P00.00 (speed control mode, range 0-3) and P00.07 (frequency command B, default 15) were here
once, without a source; they are gone (issue 46): a series takes them from its own manual's
table, or from the Goodrive200A's, unconfirmed, whose range the drive checks.

Marks as in the manual: `read_only` ("●", e.g. the fault history P07.27-P07.32) and
`locked_while_running` ("◎": writable only when the drive is stopped; exception 08H otherwise).
No row carries "◎" here: PROTOCOL.md's frames write P00.03 right after a run command and
expect an echo, so the frequency limits are not locked (a series' own manual says otherwise
where it does: the GD20's and GD200A's P00.03 is "◎"). (The
Goodrive200A manual marks P00.03-P00.05 "◎": its table says so.)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

from gateway.profile.addressing import format_parameter, parse_parameter


@dataclass(frozen=True)
class Parameter:
    name: str
    """Pxx.yy"""
    description: str
    decimals: int = 0
    unit: str = ""
    default: int = 0
    """Raw value, i.e. already x 10^decimals."""
    minimum: int = 0
    maximum: int = 0xFFFF
    minimum_from: str | None = None
    maximum_from: str | None = None
    read_only: bool = False
    locked_while_running: bool = False
    choices: tuple[tuple[int, str], ...] = ()
    """The manual's words for each value ("2" → "SVPWM (V/F) control"), in order."""
    hint: str = ""
    """How to read a value that is not one choice: its bits or digits ("bit 0-8: S1-S8; HDI")."""
    hexadecimal: bool = False
    """The manual writes its values in hex (bit masks, digit-coded settings: 0x1FF)."""
    default_known: bool = True
    """False: the manual's default "depends on model"; `default` is then only what a simulated
    drive starts with."""
    confirmed: bool = True
    """False: taken from another series' manual; this series' own table was not reachable."""
    source: str = ""
    """Where the row comes from: manual, section, page."""
    note: str = ""
    """What the source leaves unclear about this row (a garbled range, a shifted name)."""
    action: str = ""
    """What writing it sets off, when it is a command rather than a setting ("restores the
    factory defaults"): never saved nor restored."""
    reinitialises: tuple[str, ...] = ()
    """Parameters the drive sets back to their defaults when this one is written (P02.01, the
    motor's rated power, re-initialises P02.02-P02.10)."""
    factory: str = ""
    """What the factory set here, when the manual says it did (the bar codes P07.21-P07.26):
    one drive's own, never copied to another."""

    @property
    def address(self) -> int:
        return parse_parameter(self.name)

    @property
    def group(self) -> str:
        """ "P00" for P00.11."""
        return self.name.split(".")[0]

    @property
    def signed(self) -> bool:
        """Negative values allowed: the register holds them in two's complement."""
        return self.minimum < 0

    def number(self, raw: int) -> int:
        """The register word as the range reads it: two's complement when the range is signed."""
        return raw - 0x10000 if self.signed and raw >= 0x8000 else raw

    def word(self, number: int) -> int:
        """The register word of a number in the range's units (the inverse of `number`)."""
        return number & 0xFFFF

    def choice(self, raw: int) -> str | None:
        """The manual's words for a value, or None when the manual gives none for it."""
        return next((words for value, words in self.choices if value == raw), None)

    def show_number(self, number: int) -> str:
        """A number of the range's scale without its unit ("-300.0", "400.00", "0x01FF")."""
        if self.hexadecimal and not self.decimals:
            return f"0x{number & 0xFFFF:04X}"
        return f"{number / 10**self.decimals:.{self.decimals}f}" if self.decimals else str(number)

    def range_text(self) -> str:
        """The manual's range with its unit, and the parameters that bound it at run time:
        "0.00 ... 400.00 Hz, within P00.05 ... P00.03"."""
        text = f"{self.show_number(self.minimum)} ... {self.show_number(self.maximum)}"
        text = f"{text} {self.unit}".rstrip()
        low, high = self.minimum_from, self.maximum_from
        if low and high:
            return f"{text}, within {low} ... {high}"
        if low or high:
            return f"{text}, {'at least' if low else 'at most'} {low or high}"
        return text

    def shown_default(self) -> str | None:
        """The factory's value as `show` writes it; None where the manual says it "depends on
        model" (then whether a value differs from it can't be told)."""
        return self.show(self.default) if self.default_known else None

    def show(self, raw: int) -> str:
        """ "50.00 Hz", "-50.0 %", "0x01FF", "2 (SVPWM (V/F) control)"."""
        if self.hexadecimal and not self.decimals:
            return f"0x{raw:04X}"
        number = self.number(raw)
        value = f"{number / 10**self.decimals:.{self.decimals}f}" if self.decimals else str(number)
        text = f"{value} {self.unit}".rstrip()
        choice = self.choice(raw)
        return f"{text} ({choice})" if choice else text


_P = Parameter
_MAX_HZ: Final = 63000
"""P00.03's upper end, 630.00 Hz; the frequencies it bounds (P00.04, P00.05, P00.10, P08.06)
can't go beyond it either, so it is their outer range too."""
PARAMETERS: Final[tuple[Parameter, ...]] = (
    _P(
        "P00.01",
        "run command channel: 0 keypad, 1 terminal, 2 communication",
        maximum=2,
        choices=((0, "keypad"), (1, "terminal"), (2, "communication")),
    ),
    _P("P00.02", "communication run command channel", maximum=3),
    _P(
        "P00.03",
        "max. output frequency",
        2,
        "Hz",
        default=5000,
        maximum=_MAX_HZ,
        minimum_from="P00.04",
    ),
    _P(
        "P00.04",
        "upper limit of the running frequency",
        2,
        "Hz",
        default=5000,
        maximum=_MAX_HZ,
        minimum_from="P00.05",
        maximum_from="P00.03",
    ),
    _P(
        "P00.05",
        "lower limit of the running frequency",
        2,
        "Hz",
        maximum=_MAX_HZ,
        maximum_from="P00.04",
    ),
    _P("P00.06", "frequency command A: 0 keypad, 8 Modbus", maximum=15),
    _P(
        "P00.10",
        "keypad set frequency",
        2,
        "Hz",
        default=5000,
        maximum=_MAX_HZ,
        maximum_from="P00.03",
    ),
    _P("P00.11", "acceleration time 1", 1, "s", default=100, maximum=36000, default_known=False),
    _P("P00.12", "deceleration time 1", 1, "s", default=100, maximum=36000, default_known=False),
    _P(
        "P00.13",
        "running direction: 0 default, 1 reverse, 2 reverse forbidden",
        maximum=2,
        choices=((0, "default"), (1, "reverse"), (2, "reverse forbidden")),
    ),
    _P("P01.20", "hibernation restore delay", 1, "s", maximum=36000),
    _P("P07.27", "type of current fault", read_only=True),
    _P("P07.28", "type of last fault", read_only=True),
    _P("P07.29", "type of last but one fault", read_only=True),
    _P("P07.30", "type of last but two fault", read_only=True),
    _P("P07.31", "type of last but three fault", read_only=True),
    _P("P07.32", "type of last but four fault", read_only=True),
    _P(
        "P08.06",
        "jog running frequency",
        2,
        "Hz",
        default=500,
        maximum=_MAX_HZ,
        maximum_from="P00.03",
    ),
    _P("P08.07", "jog acceleration time", 1, "s", default=100, maximum=36000, default_known=False),
    _P("P08.08", "jog deceleration time", 1, "s", default=100, maximum=36000, default_known=False),
    _P("P14.00", "local communication address", default=1, minimum=1, maximum=247),
    _P("P14.01", "baud rate: 0-7 = 1200...115200", default=4, maximum=7),
    _P("P14.02", "data format: 0-5 = N81, E81, O81, N82, E82, O82", default=1, maximum=5),
    _P("P14.03", "communication response delay", 0, "ms", default=5, maximum=200),
    _P("P14.04", "communication timeout fault time (0.0 = off)", 1, "s", maximum=600),
)
del _P, _MAX_HZ

FAULT_HISTORY: Final = ("P07.27", "P07.28", "P07.29", "P07.30", "P07.31", "P07.32")
"""Newest first: the current fault, then the five before it."""

BAUD_RATES: Final = (1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200)
"""P14.01 index → baud."""
DATA_FORMATS: Final = (("N", 1), ("E", 1), ("O", 1), ("N", 2), ("E", 2), ("O", 2))
"""P14.02 index → (parity, stop bits), always 8 data bits."""

_BY_NAME: Final = {parameter.name: parameter for parameter in PARAMETERS}
_BY_ADDRESS: Final = {parameter.address: parameter for parameter in PARAMETERS}


def parameter(name: str) -> Parameter:
    """The known parameter called `name` ("P00.11", case-insensitive)."""
    key = format_parameter(parse_parameter(name))
    try:
        return _BY_NAME[key]
    except KeyError:
        raise ValueError(
            f"{key} is not in the profile's parameter table: its decimals are unknown, "
            f"write a raw value instead"
        ) from None


def parameter_at(address: int) -> Parameter | None:
    """The known parameter at a register address (without the RAM bit), or None."""
    return _BY_ADDRESS.get(address)


def parameter_decimals(name: str) -> int:
    return parameter(name).decimals


def scale_parameter(name: str, value: float) -> int:
    """Raw register value of an engineering value: `scale_parameter("P00.11", 10.0) == 100`."""
    raw = round(value * float(10 ** parameter(name).decimals))
    if not 0 <= raw <= 0xFFFF:
        raise ValueError(f"{name} = {value} does not fit in one register")
    return raw


def unscale_parameter(name: str, raw: int) -> float | int:
    """Engineering value of a raw register value: `unscale_parameter("P00.03", 5000) == 50.0`."""
    decimals = parameter(name).decimals
    return raw / float(10**decimals) if decimals else raw


def parameter_groups(parameters: tuple[Parameter, ...]) -> dict[str, tuple[Parameter, ...]]:
    """ "P00" → the parameters of group 00, in table order."""
    groups: dict[str, list[Parameter]] = {}
    for spec in parameters:
        groups.setdefault(spec.name.split(".")[0], []).append(spec)
    return {group: tuple(specs) for group, specs in groups.items()}
