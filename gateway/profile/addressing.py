"""How INVT numbers its registers: `Pxx.yy` parameters, RAM-only writes, register spellings.

From the INVT communication chapters: "the high byte is the group number, the low byte the index
in the group", both written in decimal, so P07.27 → 071BH and P10.01 → 0A01H. Setting the top bit
(P00.07 → 8007H) writes RAM only, sparing the EEPROM; such an address can be written, not read.
"""

from __future__ import annotations

import re
from typing import Final

RAM_BIT: Final = 0x8000
MAX_GROUP: Final = 99
MAX_INDEX: Final = 99

_PARAMETER = re.compile(r"P(\d{1,2})\.(\d{1,2})", re.IGNORECASE)
_HEX_SUFFIX = re.compile(r"([0-9A-F]{1,4})H", re.IGNORECASE)


def parse_parameter(text: str) -> int:
    """The register of a parameter name: `parse_parameter("P00.11") == 0x000B`."""
    match = _PARAMETER.fullmatch(text.strip())
    if match is None:
        raise ValueError(f"{text!r} is not a parameter name: expected Pxx.yy, e.g. P00.11")
    group, index = int(match.group(1)), int(match.group(2))
    return parameter_register(group, index)


def parameter_register(group: int, index: int) -> int:
    """(group << 8) | index, both checked against 0..99."""
    if not 0 <= group <= MAX_GROUP:
        raise ValueError(f"parameter group {group} is outside 0..{MAX_GROUP}")
    if not 0 <= index <= MAX_INDEX:
        raise ValueError(f"parameter index {index} is outside 0..{MAX_INDEX}")
    return (group << 8) | index


def format_parameter(address: int) -> str:
    """The parameter name of a register: `format_parameter(0x071B) == "P07.27"`.

    A RAM-only address names the same parameter: `format_parameter(0x8007) == "P00.07"`.
    """
    if not 0 <= address <= 0xFFFF:
        raise ValueError(f"register {address} is outside 0000H..FFFFH")
    group, index = (address & ~RAM_BIT) >> 8, address & 0xFF
    if group > MAX_GROUP or index > MAX_INDEX:
        raise ValueError(
            f"register {address:04X}H is not a parameter (group {group}, index {index}: "
            f"both must be 0..99)"
        )
    return f"P{group:02d}.{index:02d}"


def is_parameter_register(address: int) -> bool:
    """True when `address` (RAM bit ignored) has a group and an index of 0..99."""
    plain = address & ~RAM_BIT
    return 0 <= address <= 0xFFFF and plain >> 8 <= MAX_GROUP and plain & 0xFF <= MAX_INDEX


def ram_address(address: int) -> int:
    """The RAM-only (no EEPROM) address of a parameter register: 0007H → 8007H."""
    if not 0 <= address < RAM_BIT:
        raise ValueError(f"register {address:#x} has no RAM-only address (must be below 8000H)")
    return address | RAM_BIT


def is_ram_address(address: int) -> bool:
    return bool(address & RAM_BIT)


def parse_register(text: str) -> int:
    """A register address as people write it: "2100H", "0x2100", "8448" or "P00.11"."""
    spelled = text.strip()
    if _PARAMETER.fullmatch(spelled):
        return parse_parameter(spelled)
    hex_match = _HEX_SUFFIX.fullmatch(spelled)
    try:
        if hex_match is not None:
            value = int(hex_match.group(1), 16)
        elif spelled.lower().startswith("0x"):
            value = int(spelled, 16)
        else:
            value = int(spelled, 10)
    except ValueError:
        raise ValueError(
            f"{text!r} is not a register: write 2100H, 0x2100, 8448 or P00.11"
        ) from None
    if not 0 <= value <= 0xFFFF:
        raise ValueError(f"register {text!r} is outside 0000H..FFFFH")
    return value


def format_register(address: int) -> str:
    """INVT's spelling of a register address: 0x2100 → "2100H"."""
    return f"{address:04X}H"
