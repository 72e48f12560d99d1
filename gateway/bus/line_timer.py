"""Exact wake-ups on the event loop, for the inter-frame gap.

asyncio's selector rounds every timeout up to whole milliseconds (epoll takes milliseconds), so a
1.75 ms gap kept with `loop.call_at` would become 2-3 ms and a 115200-baud line would lose a
quarter of its capacity. A Linux timerfd is a file descriptor that becomes readable at a
nanosecond deadline: the loop watches it like any socket, and the wake-up comes when the gap ends,
not at the next millisecond. The kernel applies no timer slack to it either.

Where timerfd is missing (not Linux, or the call is refused) the timer falls back to `call_at`:
the gap is still kept, only less tightly.

A busy loop makes any wake-up late: the timer's callback waits behind every other callback of
its pass (a request from each of 32 clients, replies on 15 other lines). So the work that fills
those passes calls `LineTimer.fire_due` (the bus after queueing a request, the line after taking
bytes in): a gap that has ended meanwhile is acted on there, a callback's length late at most,
not a pass's.
"""

from __future__ import annotations

import asyncio
import ctypes
import logging
import math
import os
import time
import weakref
from collections.abc import Callable

from gateway import timerfd
from gateway.bus.wakeup import NeverEarly, settle
from gateway.timerfd import DeadlineTimer

log = logging.getLogger(__name__)

_INF = math.inf
"""`math.inf` as a module global: read once per transaction or more, and `math.inf` is a
global read and an attribute read."""


_ARMED: weakref.WeakKeyDictionary[asyncio.AbstractEventLoop, set[LineTimer]] = (
    weakref.WeakKeyDictionary()
)
"""The timers waiting for a deadline, per event loop: what `LineTimer.fire_due` looks through."""


class LineTimer:
    """One pending deadline at a time; `sleep_until` returns once it has passed."""

    def __init__(self, loop: asyncio.AbstractEventLoop) -> None:
        self._loop = loop
        self.waiting: asyncio.Future[None] | None = None
        """What `sleep_until` awaits now (for an `at_deadline` that takes the wait over). An
        attribute, not a property: the line reads it once per transaction, and a property's
        call costs ~600 instructions more than an attribute's read on Python 3.11."""
        self._at_deadline: Callable[[], bool] | None = None
        self._deadline = _INF
        """Of the pending sleep, until its deadline has been acted on; inf otherwise."""
        self.loop_armed: set[LineTimer] = _ARMED.setdefault(loop, set())
        """The timers of this loop's lines armed now, this one's too (shared, never replaced):
        a caller that knows only its own can be due skips `fire_due`'s call and clock read."""
        self._fallback: NeverEarly | None = None
        """The loop's timer for the pending sleep where there is no timerfd."""
        self._timerfd = DeadlineTimer()
        self._fd = self._timerfd.fd
        """The timerfd's (-1: none), read once per transaction or more."""
        if self._fd >= 0:
            loop.add_reader(self._fd, self._expired)
        elif timerfd.libc() is not None:
            log.debug("timerfd_create failed (errno %d); gaps kept to 1 ms", ctypes.get_errno())

    def fire_due(self) -> None:
        """Act now on every gap of this timer's loop (its own or another line's) that has ended,
        rather than when that timer's wake-up gets its turn in the loop's pass (see the module's
        docstring). Cheap when none has: a clock read."""
        armed = self.loop_armed
        if not armed:
            return
        now = time.monotonic()
        for timer in armed:
            if timer._deadline <= now:
                break
        else:
            return  # the usual case, twice per transaction: nothing due, nothing built
        for timer in [timer for timer in armed if timer._deadline <= now]:
            timer._fire_early()

    @property
    def exact(self) -> bool:
        """True when wake-ups come at the deadline (timerfd), not at the next millisecond."""
        return self._fd >= 0

    async def sleep_until(
        self, deadline: float, at_deadline: Callable[[], bool] | None = None
    ) -> None:
        """Return at `deadline` (a `time.monotonic()` value) or right after it.

        `at_deadline` runs inside the timer's own callback, in the wake-up that ends the wait,
        before the waiting coroutine resumes (which costs the loop one more pass): the line
        writes its next frame there. It doesn't run when the deadline has already passed (the
        caller acts at once then) or when the timer is closed. When it returns True it has
        taken the wait over (`waiting`): the coroutine resumes once its taker settles it, not at
        once (the line: when its reply needs the caller's own reading; it may `rearm` the wait
        for the next gap meanwhile).
        """
        if deadline <= time.monotonic():
            return
        waiter = self._loop.create_future()
        self.waiting, self._at_deadline = waiter, at_deadline
        self._deadline = deadline
        self.loop_armed.add(self)
        try:
            if self._fd >= 0 and self._timerfd.arm_at(deadline):
                await waiter
                return
            # asyncio's loop timer rounds up to the next millisecond, uvloop's to the nearest:
            # it may come early, and an RTS delay or a gap nothing else checks must not end so.
            self._fallback = NeverEarly(self._loop, deadline, self._deadline_reached)
            try:
                await waiter
            finally:
                if self._fallback is not None:
                    self._fallback.cancel()
                    self._fallback = None
        finally:
            if self.waiting is waiter:  # not a newer sleep's, if this one ended late
                self.waiting = self._at_deadline = None
                self._deadline = _INF
                self.loop_armed.discard(self)

    def rearm(self, deadline: float, at_deadline: Callable[[], bool]) -> bool:
        """Give a wait that its `at_deadline` took over (returned True) another deadline and
        action, the waiting coroutine held still: the line sends frame after frame so, from
        its callbacks, while the bus's coroutine sleeps. False when it can't (no exact timer,
        or the wait is over): whoever took the wait over settles `waiting` then.
        """
        waiter = self.waiting
        if waiter is None or waiter.done() or self._fd < 0:
            return False
        if not self._timerfd.arm_at(deadline):
            return False
        self._at_deadline, self._deadline = at_deadline, deadline
        self.loop_armed.add(self)
        return True

    def take_over(self) -> bool:
        """Take the pending wait's action over now, before its deadline (the waiting coroutine
        held still): it won't run. False when there is no such wait. Like an action that
        returns True, whoever takes it over settles `waiting` or `rearm`s it. The timerfd
        stays armed: its wake-up, if it still comes, finds nothing to do."""
        waiter = self.waiting
        if waiter is None or waiter.done() or self._deadline == _INF:
            return False
        self._deadline = _INF
        self.loop_armed.discard(self)
        self._at_deadline = None
        return True

    def close(self) -> None:
        self.loop_armed.discard(self)
        fd, self._fd = self._fd, -1
        if fd >= 0:
            self._loop.remove_reader(fd)
        self._timerfd.close()
        if self.waiting is not None:
            settle(self.waiting)

    def _fire_early(self) -> None:
        """`fire_due` found the deadline passed before the timer's own wake-up came: take that
        wake-up's expiry (it would cost the loop a pass for nothing) and act now.

        Read, not disarmed: the deadline has passed, so the kernel has nearly always expired
        the timer already, and reading the count is a cheaper system call than a timerfd write.
        Where it hasn't yet (its expiry may come tens of microseconds late on a VM), disarmed."""
        if self._fd >= 0:
            try:
                os.read(self._fd, 8)
            except BlockingIOError:
                self._timerfd.disarm()
        self._deadline_reached()

    def _expired(self) -> None:
        # The expiry count read first (or the loop would find the timer readable on every
        # pass), and it says whether to act, without a clock read: the read succeeds only if
        # the deadline armed now has passed (arming clears the count). It fails when the timer
        # was armed again for later after this wake-up was queued (or disarmed, `_fire_early`),
        # and when it is closed (-1). A deadline taken over or acted on already: nothing
        # pending, `_deadline_reached` finds.
        try:
            os.read(self._fd, 8)
        except OSError:
            return
        self._deadline_reached()

    def _deadline_reached(self) -> None:
        waiter, action = self.waiting, self._at_deadline
        if waiter is None or waiter.done() or self._deadline == _INF:
            return
        # Acted on once only: whichever comes first, the wake-up or `fire_due`.
        self._deadline = _INF
        self.loop_armed.discard(self)
        self._at_deadline = None
        taken = False
        try:
            taken = action is not None and action()
        finally:
            if not taken:
                settle(waiter)  # whatever else the action did, the waiting coroutine goes on
