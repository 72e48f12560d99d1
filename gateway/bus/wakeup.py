"""Waking a waiting coroutine: by whoever has news for it, or by its own timeout.

The bus and the line wait on a bare future that callbacks settle (a reply's bytes, a request, the
gap timer), rather than on events or `wait_for`, which would cost a task or a timer handle more per
transaction.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Callable
from functools import partial


def settle(waiter: asyncio.Future[None]) -> None:
    """Wake `waiter`'s coroutine; nothing if it is awake already."""
    if not waiter.done():
        waiter.set_result(None)


class NeverEarly:
    """The loop's timer, calling `action` at `deadline` (a `time.monotonic()` value) or after it,
    never before.

    uvloop rounds a timer to the nearest millisecond (under half a millisecond: the next pass of
    the loop), so its callback may run before the time is up; this one then waits out the rest.
    An echo's or a character's timeout that ended early would give up on bytes still coming, an
    RTS set-up delay that ended early would cut the frame's first bits.
    """

    __slots__ = ("_action", "_deadline", "_handle", "_loop")

    def __init__(
        self, loop: asyncio.AbstractEventLoop, deadline: float, action: Callable[[], object]
    ) -> None:
        self._loop, self._deadline, self._action = loop, deadline, action
        self._handle = loop.call_later(max(deadline - time.monotonic(), 0.0), self._due)

    def cancel(self) -> None:
        self._handle.cancel()

    def _due(self) -> None:
        remaining = self._deadline - time.monotonic()
        if remaining > 0:
            self._handle = self._loop.call_later(remaining, self._due)
        else:
            self._action()


class MovingDeadline:
    """A deadline set anew for every transaction (a response timeout), watched by one loop
    timer that is moved only when it comes due: `action` runs at the deadline or after it,
    never before, and only if the deadline is still set then.

    A busy line sets a response timeout a few milliseconds after the last one was cleared:
    arming a timer for each (a timerfd write, or a timer handle pushed and cancelled) costs
    every transaction. Here setting it is two float stores while a timer is pending no later
    than the new deadline; that timer, when it fires, finds the deadline of the transaction on
    the line by then and waits again for it. So the loop's timer moves about once per timeout's
    length, not once per transaction.
    """

    __slots__ = ("_action", "_handle", "_loop", "deadline", "handle_at")

    def __init__(self, loop: asyncio.AbstractEventLoop, action: Callable[[], object]) -> None:
        self._loop, self._action = loop, action
        self.deadline = math.inf
        """Of the current transaction; inf when none is set. A user may store a new deadline
        here directly while it is no earlier than `handle_at` (the timer pending comes no
        later), and must call `set` otherwise; storing inf clears it, as `clear` does."""
        self._handle: asyncio.TimerHandle | None = None
        self.handle_at = math.inf
        """When the pending timer fires (a `time.monotonic()` value); inf when none is."""

    def set(self, deadline: float) -> None:
        self.deadline = deadline
        if deadline < self.handle_at:  # no timer yet, or one that would come too late
            if self._handle is not None:
                self._handle.cancel()
            self._start(deadline)

    def clear(self) -> None:
        """No deadline now. The timer stays: the next `set` likely comes before it fires."""
        self.deadline = math.inf

    def close(self) -> None:
        self.deadline = math.inf
        if self._handle is not None:
            self._handle.cancel()
            self._handle, self.handle_at = None, math.inf

    def _start(self, at: float) -> None:
        self.handle_at = at
        self._handle = self._loop.call_later(max(at - time.monotonic(), 0.0), self._fired)

    def _fired(self) -> None:
        self._handle, self.handle_at = None, math.inf
        deadline = self.deadline
        if deadline == math.inf:
            return  # nothing to watch: the next `set` starts a timer
        if deadline > time.monotonic():
            # A later transaction's deadline, or uvloop's rounding to the nearest millisecond.
            self._start(deadline)
            return
        self.deadline = math.inf
        self._action()


async def woken_or_timeout(waiter: asyncio.Future[None], timeout_s: float) -> None:
    """Wait until someone calls `settle(waiter)`, or `timeout_s` has passed: never less."""
    timer = NeverEarly(
        asyncio.get_running_loop(), time.monotonic() + timeout_s, partial(settle, waiter)
    )
    try:
        await waiter
    finally:
        timer.cancel()
