"""The gap timer: a gap is never cut short, a timer being closed releases whoever waits, and a
gap that ended while the loop was busy is acted on by the busy work itself (`fire_due`)."""

from __future__ import annotations

import asyncio
import sys
import time
from collections.abc import Callable

import pytest

from gateway import timerfd
from gateway.bus.line_timer import LineTimer


async def _sleep_from_now(
    timer: LineTimer, delay_s: float, action: Callable[[], bool], deadlines: list[float]
) -> None:
    """Sleep `delay_s` from when this coroutine first runs, not from when its task was made: on
    a busy machine the task may start after a deadline set earlier, and a deadline already
    passed is acted on by nobody (`sleep_until` returns at once), which is not what is tested."""
    deadlines.append(time.monotonic() + delay_s)
    await timer.sleep_until(deadlines[-1], action)


async def test_sleep_until_never_returns_before_the_deadline() -> None:
    timer = LineTimer(asyncio.get_running_loop())
    try:
        for gap_s in (0.0002, 0.00175, 0.004, 0.0175):
            deadline = time.monotonic() + gap_s
            await timer.sleep_until(deadline)
            assert time.monotonic() >= deadline
    finally:
        timer.close()


async def test_without_a_timerfd_a_gap_still_never_ends_early(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Where there is no timerfd the loop's own timer keeps the gap; uvloop's comes up to half
    a millisecond early (it rounds to the nearest), asyncio's rounds up: on both loops the
    sleep lasts at least until its deadline, sub-millisecond gaps (RTS delays) included."""
    monkeypatch.setattr(timerfd, "libc", lambda: None)  # as on a system without timerfd
    timer = LineTimer(asyncio.get_running_loop())
    try:
        assert not timer.exact
        for n in range(40):
            deadline = time.monotonic() + 0.0001 + 0.00005 * n  # 0.1-2.05 ms
            await timer.sleep_until(deadline)
            assert time.monotonic() >= deadline, f"gap {n} ended early"
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


async def test_a_gap_that_ends_during_a_long_callback_is_acted_on_from_inside_it() -> None:
    """What the bus and the line call while a pass of the loop is busy (32 clients' requests,
    replies on 15 other lines): the line's next frame goes out a callback late, not a pass."""
    loop = asyncio.get_running_loop()
    timer = LineTimer(loop)
    other_line = LineTimer(loop)  # the busy work is another line's: one set of timers per loop
    acted: list[str] = []

    def busy_callback() -> None:
        other_line.fire_due()
        acted.append("before the deadline: nothing")
        while time.monotonic() < deadlines[0] + 0.002:  # a busy pass; the gap ends meanwhile
            time.sleep(0.001)
        other_line.fire_due()
        acted.append("busy callback ends")

    def at_deadline() -> bool:
        acted.append("gap action")
        return False

    deadlines: list[float] = []
    sleeping = loop.create_task(_sleep_from_now(timer, 0.05, at_deadline, deadlines))
    await asyncio.sleep(0)  # the sleep is armed
    loop.call_soon(busy_callback)
    try:
        await asyncio.wait_for(sleeping, 1.0)
        await asyncio.sleep(0.01)  # the timer's own wake-up, disarmed, must not act again
        assert acted == ["before the deadline: nothing", "gap action", "busy callback ends"]
        assert time.monotonic() >= deadlines[0]
    finally:
        timer.close()
        other_line.close()


async def test_an_action_that_took_the_wait_over_is_not_released_by_a_later_fire_due() -> None:
    """The line holds its caller until the reply's first bytes: neither the timer's own wake-up
    nor another `fire_due` may release it before then."""
    loop = asyncio.get_running_loop()
    timer = LineTimer(loop)
    taken: list[bool] = []

    def take_the_wait_over() -> bool:
        taken.append(True)
        return True

    deadlines: list[float] = []
    sleeping = loop.create_task(_sleep_from_now(timer, 0.005, take_the_wait_over, deadlines))
    await asyncio.sleep(0)  # the sleep is armed
    await asyncio.sleep(deadlines[0] + 0.005 - time.monotonic())  # the deadline is past
    timer.fire_due()
    await asyncio.sleep(0.01)
    assert taken == [True]
    assert not sleeping.done()  # still held: its taker has not settled it
    waiting = timer.waiting
    assert waiting is not None
    waiting.set_result(None)  # the reply's first bytes
    await asyncio.wait_for(sleeping, 1.0)
    timer.close()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="timerfd is Linux's")
async def test_a_wait_taken_over_can_be_rearmed_without_waking_its_coroutine() -> None:
    """The line sends frame after frame from its callbacks: each gap is a new deadline on the
    same held wait, acted on never before it, and the coroutine wakes only when an action
    lets it go."""
    loop = asyncio.get_running_loop()
    timer = LineTimer(loop)
    acted: list[tuple[str, float]] = []
    deadlines: list[float] = []

    def first_gap() -> bool:
        acted.append(("first", time.monotonic()))
        deadlines.append(time.monotonic() + 0.003)
        assert timer.rearm(deadlines[-1], second_gap)  # the wait stays taken over
        return True

    def second_gap() -> bool:
        acted.append(("second", time.monotonic()))
        return False  # nothing more to send: the coroutine goes on

    # Far enough ahead that the wait is still to come when wait_for's task first runs (a
    # deadline already passed is the caller's to act on, and nothing is run: sleep_until).
    deadlines.append(time.monotonic() + 0.05)
    try:
        await asyncio.wait_for(timer.sleep_until(deadlines[0], first_gap), 1.0)
        assert [name for name, _ in acted] == ["first", "second"]
        assert all(at >= deadline for (_, at), deadline in zip(acted, deadlines, strict=True))
        assert not timer.rearm(time.monotonic() + 0.001, second_gap)  # the wait is over
    finally:
        timer.close()


async def test_an_action_that_closes_the_timer_leaves_nothing_behind() -> None:
    """A port that fails as the gap ends closes the line, and its timer, from inside the timer's
    own wake-up: the closed timer must not be read afterwards (an error in the loop's log)."""
    loop = asyncio.get_running_loop()
    errors: list[dict[str, object]] = []
    loop.set_exception_handler(lambda _loop, context: errors.append(context))
    timer = LineTimer(loop)

    failed: list[bool] = []

    def port_fails() -> bool:
        failed.append(True)
        timer.close()
        return False

    try:
        await asyncio.wait_for(_sleep_from_now(timer, 0.002, port_fails, []), 1.0)
        await asyncio.sleep(0.01)
        assert failed == [True]
        assert errors == []
    finally:
        loop.set_exception_handler(None)
