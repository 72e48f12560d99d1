"""INVT fault codes, as read from 2102H, 5000H (GD350) and P07.27-P07.32, one table per series.

Each drive profile carries its own `FaultTable`: a code outside it is "unknown fault N" for that
drive, never another series' name for the same number (a GD20 reporting 40 is not a GD350's STO).

- `GOODRIVE_FAULTS`: codes 0-36, the table the Goodrive communication chapters share (GD10, GD20,
  GD35, GD100, GD300).
- Goodrive200A: only the codes its own manual's P07.27 lists (0-28, 32, 33, 36: no 29-31, 34 or
  35), described as the common table describes them (`FaultTable.only`, built in `invt`).
- `GD350_FAULTS`: the GD350 family (GD350, GD350A, GD350-UL) goes on to 69; its manual gives short
  codes only for 37-69, so they are shown as the short code alone.
- Goodrive30, IPE300 and Goodrive300-LIFT: no public fault list was found for them. Their
  communication chapters were reachable (the IPE300's and the GD300-LIFT's name 35 STo in their
  P07.27-P07.32 example), their fault chapters (GD300-LIFT 8.5 "Inverter faults and solutions",
  page 95) were not; see the protocol notes in the README. Their tables are the common Goodrive
  one, marked unconfirmed, and a site corrects them with `drives[].faults` in the config
  (`with_overrides`).

`FAULTS`, `describe_fault` and `fault_short_code` without a table use the GD350 family's table,
the widest one: what `decode-fault` without `--model` shows.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Final

NO_FAULT: Final = 0
COMMUNICATION_FAULT: Final = 18
"""CE: raised when no request arrives within P14.04 (communication timeout)."""

_GOODRIVE: Final[dict[int, tuple[str, str]]] = {
    0: ("", "none"),
    1: ("OUt1", "inverter unit phase U protection"),
    2: ("OUt2", "inverter unit phase V protection"),
    3: ("OUt3", "inverter unit phase W protection"),
    4: ("OC1", "overcurrent while accelerating"),
    5: ("OC2", "overcurrent while decelerating"),
    6: ("OC3", "overcurrent at constant speed"),
    7: ("OV1", "overvoltage while accelerating"),
    8: ("OV2", "overvoltage while decelerating"),
    9: ("OV3", "overvoltage at constant speed"),
    10: ("UV", "bus undervoltage"),
    11: ("OL1", "motor overload"),
    12: ("OL2", "drive overload"),
    13: ("SPI", "input phase loss"),
    14: ("SPO", "output phase loss"),
    15: ("OH1", "rectifier overheat"),
    16: ("OH2", "inverter module overheat"),
    17: ("EF", "external fault"),
    18: ("CE", "RS-485 communication fault"),
    19: ("ItE", "current detection fault"),
    20: ("tE", "autotuning fault"),
    21: ("EEP", "EEPROM fault"),
    22: ("PIDE", "PID feedback lost"),
    23: ("bCE", "braking unit fault"),
    24: ("END", "running time reached"),
    25: ("OL3", "electronic overload"),
    26: ("PCE", "keypad communication fault"),
    27: ("UPE", "parameter upload fault"),
    28: ("DNE", "parameter download fault"),
    29: ("E-DP", "PROFIBUS card fault"),
    30: ("E-NET", "Ethernet card fault"),
    31: ("E-CAN", "CANopen card fault"),
    32: ("ETH1", "short circuit to ground 1"),
    33: ("ETH2", "short circuit to ground 2"),
    34: ("dEu", "speed deviation"),
    35: ("STo", "maladjustment"),
    36: ("LL", "electronic underload"),
}

# GD350 family, short codes only (the manual's table gives no more than these).
_GD350_SHORT_CODES: Final = (
    "ENC1o", "ENC1d", "ENC1Z", "STO", "STL1", "STL2", "STL3", "CrCE", "P-E1", "P-E2", "P-E3",
    "P-E4", "P-E5", "P-E6", "P-E7", "P-E8", "P-E9", "P-E10", "E-Err", "ENCU", "E-PN", "SECAN",
    "OT", "F1-Er", "F2-Er", "F3-Er", "C1-Er", "C2-Er", "C3-Er", "E-CAT", "E-BAC", "E-DEV", "S-Err",
)  # fmt: skip


@dataclass(frozen=True)
class FaultTable:
    """The fault codes one series lists: code → (keypad short code, description)."""

    name: str
    """Whose table this is, for messages: "GD350 family", "common Goodrive (unconfirmed)"."""
    entries: Mapping[int, tuple[str, str]]
    confirmed: bool = True
    """False: no public manual of the series gave this list; it is the common INVT one."""

    def knows(self, code: int) -> bool:
        return code in self.entries

    def short_code(self, code: int) -> str:
        """The keypad's short code ("STo"), or the number when the code is unknown."""
        entry = self.entries.get(code)
        if entry is None or not entry[0]:
            return "" if code == NO_FAULT else str(code)
        return entry[0]

    def code_of(self, short: str) -> int | None:
        """The code whose keypad short code is `short` ("OC1" → 4), letter case aside (the
        keypad's seven segments show "OUt1", people type "OUT1"); None when none has it."""
        wanted = short.strip().casefold()
        for code, (keypad, _) in self.entries.items():
            if keypad and keypad.casefold() == wanted:
                return code
        return None

    def describe(self, code: int) -> str:
        """ "STo: maladjustment"; "none" for 0; the short code alone when that is all the manual
        gives; "unknown fault 99" for a code not in this table."""
        entry = self.entries.get(code)
        if entry is None:
            return f"unknown fault {code}"
        short, description = entry
        if not short:
            return description
        return f"{short}: {description}" if description else short

    def only(self, listed: Iterable[tuple[int, str]], name: str) -> FaultTable:
        """The codes a series' own manual lists (`listed`: code → its keypad short code, as the
        P07.27 row's choices give them), described as this table describes the same short
        code: a code the manual leaves out is unknown for that series."""
        entries: dict[int, tuple[str, str]] = {}
        for code, short in listed:
            known = self.entries.get(code)
            if known is not None and (code == NO_FAULT or known[0].casefold() == short.casefold()):
                entries[code] = known
            else:
                entries[code] = (short, "")
        return FaultTable(name, MappingProxyType(entries), self.confirmed)

    def with_overrides(self, names: Mapping[int, str]) -> FaultTable:
        """This table with a site's corrections: code → "SHORT: description" or "SHORT"."""
        if not names:
            return self
        entries = dict(self.entries)
        for code, text in names.items():
            short, _, description = text.partition(":")
            entries[code] = (short.strip(), description.strip())
        return FaultTable(f"{self.name}, corrected in the config", MappingProxyType(entries))


GOODRIVE_FAULTS: Final = FaultTable("common Goodrive", MappingProxyType(dict(_GOODRIVE)))
GD350_FAULTS: Final = FaultTable(
    "GD350 family",
    MappingProxyType(
        {
            **_GOODRIVE,
            **{37 + offset: (short, "") for offset, short in enumerate(_GD350_SHORT_CODES)},
        }
    ),
)
UNCONFIRMED_GOODRIVE_FAULTS: Final = FaultTable(
    "common Goodrive, unconfirmed for this series", GOODRIVE_FAULTS.entries, confirmed=False
)

FAULTS: Final = GD350_FAULTS.entries
"""The widest table (GD350 family, 0-69): what a fault code means when the series isn't known."""


def fault_short_code(code: int, table: FaultTable = GD350_FAULTS) -> str:
    """The keypad's short code ("STo"), or the number when the code is unknown."""
    return table.short_code(code)


def describe_fault(code: int, table: FaultTable = GD350_FAULTS) -> str:
    """ "STo: maladjustment"; "none" for 0; "unknown fault 99" for a code not in `table`."""
    return table.describe(code)
