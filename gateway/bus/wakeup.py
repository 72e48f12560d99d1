"""Waking a waiting coroutine: by whoever has news for it, or by its own timeout.

The bus and the line wait on a bare future that callbacks settle (a reply's bytes, a request, the
gap timer), rather than on events or `wait_for`, which would cost a task or a timer handle more per
transaction.
"""

from __future__ import annotations

import asyncio
import time


def settle(waiter: asyncio.Future[None]) -> None:
    """Wake `waiter`'s coroutine; nothing if it is awake already."""
    if not waiter.done():
        waiter.set_result(None)


async def woken_or_timeout(waiter: asyncio.Future[None], timeout_s: float) -> None:
    """Wait until someone calls `settle(waiter)`, or `timeout_s` has passed: never less.

    uvloop rounds a timer to the nearest millisecond (under half a millisecond: the next pass of
    the loop), so its callback may run before the time is up; it then waits out the rest. An
    echo's or a character's timeout that ended early would give up on bytes still coming.
    """
    loop = asyncio.get_running_loop()
    deadline = time.monotonic() + timeout_s
    timer: asyncio.TimerHandle | asyncio.Handle

    def expire() -> None:
        nonlocal timer
        remaining = deadline - time.monotonic()
        if remaining > 0:
            timer = loop.call_later(remaining, expire)
        else:
            settle(waiter)

    timer = loop.call_later(timeout_s, expire)
    try:
        await waiter
    finally:
        timer.cancel()
