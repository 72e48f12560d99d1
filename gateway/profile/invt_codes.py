"""INVT's fixed addresses and its 2103H codes: which series answers which code.

Below the INVT profiles (`invt`) and their decoders (`words`, `telemetry`, `points`), so both
read these facts and the imports run one way: `invt` → the decoders → here. Each series' name
and codes are written once, in `SERIES_CODES`; `invt.InvtProfile` takes them from there.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Final

STATE_WORD_1: Final = 0x2100
FAULT_CODE: Final = 0x2102
FAULT_CODE_MIRROR: Final = 0x5000
"""A second fault-code register some series list after 3016H (GD350 family, GD300-LIFT)."""
IDENTIFICATION: Final = 0x2103
RUNNING_FREQUENCY: Final = 0x3000

GD30_PLACEHOLDER_CODE: Final = 0x01F0
IPE300_PLACEHOLDER_CODE: Final = 0x01F1
"""No public manual we could reach gives the 2103H code of a Goodrive30 or an IPE300. These
placeholders lie outside every code INVT publishes, so they are never mistaken for another
series; they are what the simulator answers, and `scan` calls them unconfirmed. A site whose
drives answer something else sets `drives[].identification` in the config."""


@dataclass(frozen=True)
class SeriesCodes:
    """An INVT series' name and the codes it answers at 2103H."""

    display_name: str
    codes: tuple[int, ...]
    """The first is the one a simulated drive answers."""
    confirmed: bool = True
    """False: no public manual gives the code; `codes` holds a placeholder."""


SERIES_CODES: Final[Mapping[str, SeriesCodes]] = MappingProxyType(
    {
        "gd20": SeriesCodes("GD20", (0x0106,)),
        "gd200a": SeriesCodes("GD200A", (0x0107, 0x010C)),
        "gd300": SeriesCodes("GD300", (0x010A,)),
        "gd350": SeriesCodes("GD350", (0x01A0,)),
        "gd350ul": SeriesCodes("GD350-UL", (0x01A1,)),
        "gd350a": SeriesCodes("GD350A", (0x01A2,)),
        "gd10": SeriesCodes("GD10", (0x010D,)),
        "gd35": SeriesCodes("GD35", (0x0108,)),
        "gd100": SeriesCodes("GD100", (0x010B,)),
        "gd30": SeriesCodes("GD30", (GD30_PLACEHOLDER_CODE,), confirmed=False),
        "ipe300": SeriesCodes("IPE300", (IPE300_PLACEHOLDER_CODE,), confirmed=False),
        # Goodrive300-LIFT's manual: 2103H "GD300-----0x010a", the GD300's code.
        "gd300l": SeriesCodes("GD300-LIFT", (0x010A,)),
    }
)
"""Series key → its name and codes, in the order a shared code lists them ("GD300 or
GD300-LIFT")."""

_SERIES_WITHOUT_PROFILE: Final = {0x0109: "GD35-H1"}
"""Codes the manuals list for series the gateway has no profile of (yet): named, not driven."""


def series_keys_for_identification(code: int) -> tuple[str, ...]:
    """The keys of every series that answers `code` at 2103H (010AH: gd300 and gd300l)."""
    return tuple(key for key, series in SERIES_CODES.items() if code in series.codes)


def model_from_identification(code: int) -> str | None:
    """ "GD350" for 01A0H, "GD300 or GD300-LIFT" for 010AH; None for a code no profile has."""
    names = [SERIES_CODES[key].display_name for key in series_keys_for_identification(code)]
    if code in _SERIES_WITHOUT_PROFILE:
        names.append(_SERIES_WITHOUT_PROFILE[code])
    return " or ".join(names) if names else None


def describe_identification(code: int) -> str:
    """What a scan shows: the series, "(01F0H unconfirmed)" after a placeholder code, or
    "unknown series (0199H)" for an INVT drive no profile places."""
    keys = series_keys_for_identification(code)
    names = model_from_identification(code)
    if names is None:
        return f"unknown series ({code:04X}H)"
    if keys and not all(SERIES_CODES[key].confirmed for key in keys):
        return f"{names} ({code:04X}H unconfirmed)"
    return names


IDENTIFICATION_CODES: Final[Mapping[int, str]] = MappingProxyType(
    {
        code: names
        for code in sorted(
            {*_SERIES_WITHOUT_PROFILE, *(c for s in SERIES_CODES.values() for c in s.codes)}
        )
        if (names := model_from_identification(code)) is not None
    }
)
"""2103H code → the series it names (GD200A answers 0107H or 010CH: the manuals disagree)."""
