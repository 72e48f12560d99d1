"""A coroutine's wait for news or its timeout: the timeout never ends it early, on either event
loop (uvloop rounds timers to the nearest millisecond), and news ends it at once."""

from __future__ import annotations

import asyncio
import time

from gateway.bus.wakeup import settle, woken_or_timeout


async def test_a_timeout_never_ends_the_wait_before_its_time() -> None:
    loop = asyncio.get_running_loop()
    for n in range(40):
        timeout_s = 0.0001 + 0.00005 * n  # 0.1-2.05 ms: character and echo timeouts
        started = time.monotonic()
        await woken_or_timeout(loop.create_future(), timeout_s)
        assert time.monotonic() - started >= timeout_s, f"wait {n} ended early"


async def test_news_ends_the_wait_at_once() -> None:
    loop = asyncio.get_running_loop()
    waiter: asyncio.Future[None] = loop.create_future()
    loop.call_soon(settle, waiter)
    started = time.monotonic()
    await woken_or_timeout(waiter, 10.0)
    assert time.monotonic() - started < 1.0
