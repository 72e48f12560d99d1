"""The gap timer: a gap is never cut short, and a timer being closed releases whoever waits."""

from __future__ import annotations

import asyncio
import sys
import time

import pytest

from gateway.bus.line_timer import LineTimer


async def test_sleep_until_never_returns_before_the_deadline() -> None:
    timer = LineTimer(asyncio.get_running_loop())
    try:
        for gap_s in (0.0002, 0.00175, 0.004, 0.0175):
            deadline = time.monotonic() + gap_s
            await timer.sleep_until(deadline)
            assert time.monotonic() >= deadline
    finally:
        timer.close()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="timerfd is Linux's")
async def test_the_gap_ends_on_a_timerfd_not_on_asyncio_milliseconds() -> None:
    timer = LineTimer(asyncio.get_running_loop())
    try:
        assert timer.exact
    finally:
        timer.close()


async def test_a_deadline_already_past_returns_at_once() -> None:
    timer = LineTimer(asyncio.get_running_loop())
    try:
        await asyncio.wait_for(timer.sleep_until(time.monotonic() - 1), 0.5)
    finally:
        timer.close()


async def test_closing_the_timer_releases_a_waiting_gap() -> None:
    loop = asyncio.get_running_loop()
    timer = LineTimer(loop)
    waiting = loop.create_task(timer.sleep_until(time.monotonic() + 60))
    await asyncio.sleep(0.01)  # the gap is under way (the timer exposes no "waiting" event)
    timer.close()
    await asyncio.wait_for(waiting, 1.0)
