"""Stopping a background task for sure, within a time budget."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time

log = logging.getLogger(__name__)

RETRY_S = 0.1


async def cancel_and_wait(task: asyncio.Task[None], budget_s: float) -> bool:
    """Cancel `task` and wait for it to end; True if it did within `budget_s`.

    One cancel is not always enough on Python 3.11: `asyncio.wait_for` swallows a cancellation
    that arrives as its inner future completes (CPython gh-86296, fixed in 3.12), and libraries
    we await (aiomqtt's publish and subscribe) use it. So cancel again until the task is done.
    """
    deadline = time.monotonic() + budget_s
    while not task.done():
        task.cancel()
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            log.error("task %s did not stop within %.1f s", task.get_name(), budget_s)
            return False
        await asyncio.wait({task}, timeout=min(RETRY_S, remaining))
    with contextlib.suppress(asyncio.CancelledError):
        exception = task.exception()
        if exception is not None:
            log.error("task %s ended with %r", task.get_name(), exception)
    return True
