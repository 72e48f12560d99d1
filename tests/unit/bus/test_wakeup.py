"""A coroutine's wait for news or its timeout: the timeout never ends it early, on either event
loop (uvloop rounds timers to the nearest millisecond), and news ends it at once. A response
timeout set anew for every transaction (`MovingDeadline`) acts at its own deadline, never at an
earlier transaction's, and not at all once cleared."""

from __future__ import annotations

import asyncio
import time

from gateway.bus.wakeup import MovingDeadline, settle, woken_or_timeout


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


class _Acted:
    """The deadline's action: when it ran, and an event for the test to wait on."""

    def __init__(self) -> None:
        self.at: list[float] = []
        self.event = asyncio.Event()

    def __call__(self) -> None:
        self.at.append(time.monotonic())
        self.event.set()

    async def wait(self, within_s: float) -> None:
        await asyncio.wait_for(self.event.wait(), within_s)
        self.event.clear()


async def test_a_moving_deadline_never_acts_before_its_time() -> None:
    acted = _Acted()
    deadline = MovingDeadline(asyncio.get_running_loop(), acted)
    try:
        for n in range(30):
            acted.at.clear()
            due = time.monotonic() + 0.0001 + 0.0001 * n  # 0.1-3 ms
            deadline.set(due)
            await acted.wait(1.0)
            assert len(acted.at) == 1, f"deadline {n}: acted {len(acted.at)} times"
            assert acted.at[0] >= due, (
                f"deadline {n} acted {(due - acted.at[0]) * 1e6:.0f} us early"
            )
    finally:
        deadline.close()


async def test_each_transaction_is_timed_by_its_own_deadline_not_by_an_earlier_ones() -> None:
    """A busy line: each reply clears the response timeout and the next request sets a later
    one, long before the first would have passed. Only the last, never cleared, acts: at its own
    time, though the loop's timer was started for the first."""
    acted = _Acted()
    deadline = MovingDeadline(asyncio.get_running_loop(), acted)
    try:
        for _ in range(10):  # ten transactions, 5 ms each, a 20 ms response timeout
            deadline.set(time.monotonic() + 0.02)
            await asyncio.sleep(0.005)
            deadline.clear()
        assert acted.at == []
        last = time.monotonic() + 0.02
        deadline.set(last)  # a drive that never answers
        await acted.wait(1.0)
        assert len(acted.at) == 1
        assert acted.at[0] >= last
        assert deadline.deadline == float("inf")  # acted on once: nothing left to watch
    finally:
        deadline.close()


async def test_a_deadline_earlier_than_the_pending_timer_acts_on_time() -> None:
    """A shorter response timeout after a longer one (a write's after a slow read's): it must
    not wait for the timer started for the longer one."""
    acted = _Acted()
    deadline = MovingDeadline(asyncio.get_running_loop(), acted)
    try:
        deadline.set(time.monotonic() + 5.0)
        deadline.clear()
        due = time.monotonic() + 0.01
        deadline.set(due)
        await acted.wait(2.0)
        assert len(acted.at) == 1
        assert due <= acted.at[0] < due + 1.0
    finally:
        deadline.close()


async def test_a_cleared_or_closed_deadline_never_acts() -> None:
    loop = asyncio.get_running_loop()
    acted = _Acted()
    cleared = MovingDeadline(loop, acted)
    closed = MovingDeadline(loop, acted)
    cleared.set(time.monotonic() + 0.002)
    closed.set(time.monotonic() + 0.002)
    cleared.clear()
    closed.close()
    await asyncio.sleep(0.05)  # asserting an absence: nothing may act in this window
    assert acted.at == []
    cleared.close()
