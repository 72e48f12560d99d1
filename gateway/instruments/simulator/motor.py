"""The output frequency ramp, computed lazily from the time of each look.

The manual's acceleration time is the time from 0 Hz to the max. frequency (P00.03), so the ramp
rate is P00.03 / P00.11 Hz/s up and P00.03 / P00.12 Hz/s down. Frequency is signed here
(negative = reverse): going from forward to reverse ramps down to 0 at the deceleration rate,
then up at the acceleration rate.
"""

from __future__ import annotations

import math
from enum import Enum


class RampPhase(Enum):
    STEADY = "steady"
    ACCELERATING = "accelerating"
    DECELERATING = "decelerating"


class Ramp:
    def __init__(self, now: float = 0.0) -> None:
        self.frequency_hz = 0.0
        self._time = now

    def advance(self, now: float, target_hz: float, accel_hz_s: float, decel_hz_s: float) -> None:
        """Move toward `target_hz` for the time since the last call (a rate may be math.inf)."""
        remaining = now - self._time
        if remaining <= 0:
            return
        self._time = now
        frequency = self.frequency_hz
        while remaining > 0 and frequency != target_hz:
            phase = phase_toward(frequency, target_hz)
            rate = accel_hz_s if phase is RampPhase.ACCELERATING else decel_hz_s
            # Decelerating toward the other direction stops at 0 first, then accelerates.
            stop_at = target_hz if frequency * target_hz >= 0 else 0.0
            distance = abs(stop_at - frequency)
            if rate == math.inf or rate * remaining >= distance:
                frequency = stop_at
                remaining -= 0.0 if rate == math.inf else distance / rate
            else:
                frequency += math.copysign(rate * remaining, stop_at - frequency)
                remaining = 0.0
        self.frequency_hz = frequency

    def coast(self, now: float) -> None:
        """Output off at once: a coasting motor has no output frequency."""
        self.frequency_hz = 0.0
        self._time = max(self._time, now)

    def phase(self, target_hz: float) -> RampPhase:
        return phase_toward(self.frequency_hz, target_hz)


def phase_toward(frequency: float, target: float) -> RampPhase:
    if frequency == target:
        return RampPhase.STEADY
    if frequency == 0 or (frequency * target > 0 and abs(target) > abs(frequency)):
        return RampPhase.ACCELERATING
    return RampPhase.DECELERATING
