"""Waking a waiting coroutine: by whoever has news for it, or by its own timeout.

The bus and the line wait on a bare future that callbacks settle (a reply's bytes, a request, the
gap timer), rather than on events or `wait_for`, which would cost a task or a timer handle more per
transaction.
"""

from __future__ import annotations

import asyncio
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


async def woken_or_timeout(waiter: asyncio.Future[None], timeout_s: float) -> None:
    """Wait until someone calls `settle(waiter)`, or `timeout_s` has passed: never less."""
    timer = NeverEarly(
        asyncio.get_running_loop(), time.monotonic() + timeout_s, partial(settle, waiter)
    )
    try:
        await waiter
    finally:
        timer.cancel()
