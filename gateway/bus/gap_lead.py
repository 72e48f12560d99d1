"""Waking a little before the inter-frame gap ends, so that the next frame leaves as it ends.

The kernel wakes a process tens of microseconds after the deadline it asked for (more on a busy
machine, more again in a virtual one), and choosing and framing the next request takes tens more:
with the timer armed for the gap's very end, every frame would leave that much late, and that is
the gateway's own share of each transaction (`invt_gateway_bus_excess_gap_seconds`). So the line
arms its timer `lead_s` before the gap ends, chooses the next request in that wake-up, and waits
out what is left of the gap on the clock: a spin of microseconds to a few hundred, never a
frame early.

The lead is learnt from every timed wake-up: a small step longer when the request was ready only
after the gap had ended, a step shorter when it was ready before. The length of that step back
sets where the lead settles, and so how often the line spins and how many frames leave late:

- Within the loop's spin budget (`SpinBudget`: half a percent of the event loop's time, for all
  the lines on it together), the step back is a nineteenth of the step forward, and the lead
  settles where 95 % of the wake-ups come early: nearly every frame leaves as its gap ends, and
  the excess gap's tail is the wake-ups' own beyond their 95th percentile, not their whole
  spread. A line alone on its loop spins a few tens of microseconds per transaction so: within
  the budget at 9600 and 19200 baud, about at it at 115200 with back-to-back requests.
- Past the budget (many lines on one loop, each of them spinning, or the lead grown long on a
  machine whose wake-ups spread widely), the step back is three times the step forward, and the
  lead settles where a quarter of the wake-ups come early: only those spin, the median frame
  still leaves by the spread between the wake-ups' lower quartile and their median. Spinning
  more would hold up the loop's other lines as long (with 16 lines on one loop, a lead at the
  95th percentile for every line cost the worst line 19 points of its share).

The budget is looked at in the first timed wake-up half a second or more after the last look,
so the leads move between the two as the load does. A line whose spin at the 95th percentile
would be above the budget (one line at 115200 baud with requests back to back) sees its lead
saw-tooth between the two from window to window, spinning about the budget on average.
The slower the line, the longer the process sleeps and the later it wakes: each line learns its
own lead.
"""

from __future__ import annotations

import asyncio
import time
import weakref

MAX_LEAD_S = 400e-6
"""Never more (nor more than a quarter of the gap): a wake-up later than this is the machine's
trouble, which no lead mends, and a longer spin would hold up the loop's other work (other
lines, clients, and whoever's callback `LineTimer.fire_due` acts in) as long. A write queued in
the last lead of a gap waits one transaction more (`gateway.bus.bus`). A slow line's
wake-ups spread widest: at 9600 baud with 8 clients their 95th percentile was about 200 us."""
STEP_S = 3e-6
"""The lead's step longer after a late wake-up: from nothing to the 100-200 us a slow line's
wake-ups need within about fifty transactions (a second or two at 9600 baud), and small against
the wake-ups' own spread."""
STEP_BACK_S = 3 * STEP_S
"""Its step shorter after an early one past the loop's spin budget: three times as long, so that
it settles where a quarter of the wake-ups are early."""
STEP_BACK_WITHIN_BUDGET_S = STEP_S / 19
"""Its step shorter after an early one within the budget: a nineteenth, so that it settles where
95 % of the wake-ups are early."""
LOOP_SPIN_BUDGET = 0.005
"""Of the event loop's time, spent waiting out gaps on the clock by all its lines together: half
a percent of a core buys the gap's tail (see the module's docstring) and leaves the rest of the
box to the plant's other work."""
BUDGET_WINDOW_S = 0.5
"""How often the budget is looked at: often enough to follow a change of load within a second,
long enough to hold about a hundred transactions at 115200 baud."""


class SpinBudget:
    """What the lines of one event loop spend spinning, against `LOOP_SPIN_BUDGET`; it tells
    their leads which step back to take (`step_back_s`)."""

    __slots__ = ("_spun_at_start", "_window_start", "spun_s", "step_back_s", "window_ends")

    def __init__(self) -> None:
        now = time.monotonic()
        self.spun_s = 0.0
        """By every line sharing it, in all."""
        self.step_back_s = STEP_BACK_WITHIN_BUDGET_S
        self._window_start = now
        self._spun_at_start = 0.0
        self.window_ends = now + BUDGET_WINDOW_S

    @property
    def within(self) -> bool:
        return self.step_back_s == STEP_BACK_WITHIN_BUDGET_S

    def look(self, now: float) -> None:
        """The window is over: within the budget or past it, for the next one."""
        spun = self.spun_s - self._spun_at_start
        past = spun > LOOP_SPIN_BUDGET * (now - self._window_start)
        self.step_back_s = STEP_BACK_S if past else STEP_BACK_WITHIN_BUDGET_S
        self._window_start, self._spun_at_start = now, self.spun_s
        self.window_ends = now + BUDGET_WINDOW_S


_BUDGETS: weakref.WeakKeyDictionary[asyncio.AbstractEventLoop, SpinBudget] = (
    weakref.WeakKeyDictionary()
)


def loop_spin_budget(loop: asyncio.AbstractEventLoop) -> SpinBudget:
    """The spin budget every line on `loop` shares."""
    budget = _BUDGETS.get(loop)
    if budget is None:
        budget = _BUDGETS[loop] = SpinBudget()
    return budget


class GapLead:
    """How long before the gap's end the line's timer wakes it; learnt per line."""

    __slots__ = ("_max_s", "budget", "lead_s", "spun_s")

    def __init__(self, gap_s: float, budget: SpinBudget | None = None) -> None:
        # Never more than a quarter of the gap: at the highest baud rates the gap is short, and
        # the choice made at the wake-up must still be the choice of (nearly) the gap's end.
        self._max_s = min(MAX_LEAD_S, gap_s / 4)
        self.lead_s = 0.0
        self.spun_s = 0.0
        """Time spent waiting out the gap on the clock, in all: its CPU cost, for the tests
        and for anyone wondering."""
        self.budget = SpinBudget() if budget is None else budget
        """Shared with the other lines of the event loop (the line sets it as it opens)."""

    def ready(self, gap_end: float) -> float:
        """The next frame is chosen and built, in a wake-up the timer made a lead early: learn
        from how early or late that was, and wait out the rest of the gap. Returns the clock's
        last reading (`gap_end` or later): the frame may go from then, and the line takes it
        for the frame's start rather than read the clock again (once per transaction)."""
        # Once per transaction: plain comparisons rather than min() and max() calls.
        lead = self.lead_s
        budget = self.budget
        now = time.monotonic()
        if now >= budget.window_ends:
            budget.look(now)
        if now >= gap_end:
            lead += STEP_S
            self.lead_s = lead if lead < self._max_s else self._max_s
            return now
        lead -= budget.step_back_s
        self.lead_s = lead if lead > 0.0 else 0.0
        return self.wait_out(gap_end)

    def wait_out(self, gap_end: float) -> float:
        """Return at `gap_end` (a `time.monotonic()` value), not before, spinning on the clock:
        for waits far shorter than any wake-up the kernel could give. Counted in `spun_s`.
        Returns the clock's last reading (`gap_end` or later)."""
        now = started = time.monotonic()
        while now < gap_end:
            now = time.monotonic()
        spun = now - started
        self.spun_s += spun
        self.budget.spun_s += spun
        return now
