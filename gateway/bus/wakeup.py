"""Waking a waiting coroutine: by whoever has news for it, or by its own timeout.

The bus and the line wait on a bare future that callbacks settle (a reply's bytes, a request, the
gap timer), rather than on events or `wait_for`, which would cost a task or a timer handle more per
transaction.
"""

from __future__ import annotations

import asyncio


def settle(waiter: asyncio.Future[None]) -> None:
    """Wake `waiter`'s coroutine; nothing if it is awake already."""
    if not waiter.done():
        waiter.set_result(None)


async def woken_or_timeout(waiter: asyncio.Future[None], timeout_s: float) -> None:
    """Wait until someone calls `settle(waiter)`, or `timeout_s` has passed."""
    timer = asyncio.get_running_loop().call_later(timeout_s, settle, waiter)
    try:
        await waiter
    finally:
        timer.cancel()
