"""Serial line timing: character time and the 3.5-character silence that separates RTU frames.

Modbus over serial line, 2.5.1.1: above 19200 baud t3.5 is a fixed 1.75 ms, because at those
speeds the UART's own timing would make a character-based gap too short to measure.
"""

from __future__ import annotations

from typing import Final

FIXED_T35_S: Final = 0.00175
FIXED_T35_ABOVE_BAUD: Final = 19200
DATA_BITS: Final = 8


def character_time_s(baudrate: int, parity: str = "E", stopbits: int = 1) -> float:
    """Seconds one character takes: start bit + 8 data bits + parity bit (unless N) + stop bits."""
    bits = 1 + DATA_BITS + (0 if parity.upper() == "N" else 1) + stopbits
    return bits / baudrate


def t35_s(baudrate: int, parity: str = "E", stopbits: int = 1) -> float:
    """The inter-frame silence: 3.5 characters, or a fixed 1.75 ms above 19200 baud."""
    if baudrate > FIXED_T35_ABOVE_BAUD:
        return FIXED_T35_S
    return 3.5 * character_time_s(baudrate, parity, stopbits)
