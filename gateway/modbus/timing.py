"""Time on a Modbus serial line for a character format: one character, t3.5, a frame.

Shared by the bus (which keeps the gap) and the simulator (which emulates the wire).
"""

from __future__ import annotations

from dataclasses import dataclass, field

# Above 19200 baud the Modbus serial line spec fixes t3.5 at 1.75 ms instead of 3.5 characters,
# because the character time becomes so short that a PC's timers can't keep it.
FAST_BAUD = 19200
FAST_T35_S = 0.00175


@dataclass(frozen=True, slots=True)
class CharacterFormat:
    baudrate: int
    parity: str = "E"
    stopbits: int = 1
    bytesize: int = 8
    char_time_s: float = field(init=False, repr=False, compare=False)
    """One character's time on the wire: worked out once, as the line asks for a frame's
    wire time twice a transaction."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "char_time_s", self.bits_per_char / self.baudrate)

    @property
    def bits_per_char(self) -> int:
        """Start bit, data bits, a parity bit unless N, stop bits."""
        return 1 + self.bytesize + (0 if self.parity == "N" else 1) + self.stopbits

    @property
    def t35_s(self) -> float:
        """The silence that separates two frames."""
        return FAST_T35_S if self.baudrate > FAST_BAUD else 3.5 * self.char_time_s

    def wire_time_s(self, length: int) -> float:
        """How long `length` bytes take on the wire."""
        return length * self.char_time_s
