"""Waiting between attempts at something that keeps failing: doubling to a cap, with jitter.

Everything in the gateway that retries on its own waits this way: the MQTT connection, the serial
port's reopening, the probes of an offline drive and the polls of one. Each wait is drawn from the
last fifth below the nominal delay, so gateways that lost one broker together, or drives that
went silent with one line, don't try again in step, and no wait is longer than the nominal delay:
the cap a user sets (`reconnect_max_s`, `probe_max_s`) is never exceeded.
"""

from __future__ import annotations

import random

JITTER_FROM = 0.8
"""Each wait is between this share of the nominal delay and the delay itself."""


class Backoff:
    """The waits between attempts: `initial_s`, doubled after each, up to `max_s`; jittered."""

    def __init__(self, initial_s: float, max_s: float, rng: random.Random | None = None) -> None:
        self.initial_s = initial_s
        self.max_s = max(max_s, initial_s)
        self.doublings = 0
        """Waits since the last `reset` (how far the backoff has grown)."""
        self._delay_s = initial_s
        self._rng = rng or random.Random()

    @property
    def delay_s(self) -> float:
        """The nominal delay of the next wait (before jitter)."""
        return self._delay_s

    def next_delay(self) -> float:
        """The wait before the next attempt: jittered, then doubled for the one after."""
        delay = self._delay_s * self._rng.uniform(JITTER_FROM, 1.0)
        self._delay_s = min(self._delay_s * 2, self.max_s)
        self.doublings += 1
        return delay

    def reset(self) -> None:
        """It worked: the next failure starts from `initial_s` again."""
        self._delay_s = self.initial_s
        self.doublings = 0
