"""Waking a little before the inter-frame gap ends, so that the next frame leaves as it ends.

The kernel wakes a process tens of microseconds after the deadline it asked for (more on a busy
machine, more again in a virtual one), and choosing and framing the next request takes tens more:
with the timer armed for the gap's very end, every frame would leave that much late, and that is
the gateway's own share of each transaction (`invt_gateway_bus_excess_gap_seconds`). So the line
arms its timer `lead_s` before the gap ends, chooses the next request in that wake-up, and waits
out what is left of the gap on the clock: a spin of a few microseconds, never a frame early.

The lead is learnt from every timed wake-up: a small step longer when the request was ready only
after the gap had ended, a step three times as long shorter when it was ready before. It settles
where a quarter of the wake-ups come early: the median frame leaves by the spread between the
wake-ups' lower quartile and their median after the gap's end, not by their whole lateness, and
only that early quarter spins, for no longer than the wake-ups spread below their lower
quartile. Spinning longer would buy little more and hold up the loop's other work as long (with
16 lines on one loop, a lead at the median cost the other lines more than it gave). The slower
the line, the longer the process sleeps and the later it wakes: each line learns its own.
"""

from __future__ import annotations

import time

MAX_LEAD_S = 200e-6
"""Never more: a wake-up later than this is the machine's trouble, which no lead mends, and
a longer spin would hold up the loop's other work (other lines, clients) as long."""
STEP_S = 3e-6
"""The lead's step longer after a late wake-up: from nothing to the 100-200 us a slow line's
wake-ups need within about fifty transactions (a second or two at 9600 baud), and small against
the wake-ups' own spread."""
STEP_BACK_S = 3 * STEP_S
"""Its step shorter after an early one: three times as long, so that it settles where a quarter
of the wake-ups are early."""


class GapLead:
    """How long before the gap's end the line's timer wakes it; learnt per line."""

    __slots__ = ("_max_s", "lead_s", "spun_s")

    def __init__(self, gap_s: float) -> None:
        # Never more than a quarter of the gap: at the highest baud rates the gap is short, and
        # the choice made at the wake-up must still be the choice of (nearly) the gap's end.
        self._max_s = min(MAX_LEAD_S, gap_s / 4)
        self.lead_s = 0.0
        self.spun_s = 0.0
        """Time spent waiting out the gap on the clock, in all: its CPU cost, for the tests
        and for anyone wondering."""

    def ready(self, gap_end: float) -> None:
        """The next frame is chosen and built, in a wake-up the timer made a lead early: learn
        from how early or late that was, and wait out the rest of the gap."""
        # Once per transaction: plain comparisons rather than min() and max() calls.
        lead = self.lead_s
        if time.monotonic() >= gap_end:
            lead += STEP_S
            self.lead_s = lead if lead < self._max_s else self._max_s
            return
        lead -= STEP_BACK_S
        self.lead_s = lead if lead > 0.0 else 0.0
        self.wait_out(gap_end)

    def wait_out(self, gap_end: float) -> None:
        """Return at `gap_end` (a `time.monotonic()` value), not before, spinning on the clock:
        for waits far shorter than any wake-up the kernel could give. Counted in `spun_s`."""
        now = started = time.monotonic()
        while now < gap_end:
            now = time.monotonic()
        self.spun_s += now - started
