"""What one RS-485 line is configured with: its port, character format, timings and hardware."""

from __future__ import annotations

from dataclasses import dataclass

from gateway.bus.direction import DirectionControl
from gateway.modbus.timing import CharacterFormat


@dataclass(frozen=True, slots=True)
class LineSettings:
    port: str
    char_format: CharacterFormat
    gap_s: float
    char_timeout_s: float
    drain_s: float
    turnaround_s: float
    echo: bool = False
    direction: DirectionControl | None = None
    """Who switches the RS-485 driver: None for adapters that do it themselves."""
    name: str = ""
    """The bus's name, for messages; the port's path when empty."""

    @property
    def where(self) -> str:
        return f"bus {self.name} ({self.port})" if self.name else self.port
