"""Background work stops for sure: `side_by_side`, what the MQTT bridge runs its connection's
tasks with, cancels a child until it ends, not once as Python 3.11's TaskGroup does."""

from __future__ import annotations

import asyncio
import time

import pytest

from gateway.tasks import ServiceTasks, side_by_side
from tests.support import Swallower


async def forever() -> None:
    await asyncio.sleep(3600)


async def test_a_child_that_swallows_a_cancellation_is_still_stopped_within_the_budget() -> None:
    swallower = Swallower()
    running = asyncio.create_task(side_by_side({"swallower": swallower.run()}, budget_s=2.0))
    await asyncio.sleep(0.05)
    started = time.monotonic()
    running.cancel()
    with pytest.raises(asyncio.CancelledError):
        await asyncio.wait_for(running, 5.0)
    assert swallower.swallowed == 1
    assert swallower.ended
    assert time.monotonic() - started < 1.0  # cancelled again after the grace, not the budget


async def test_a_taskgroup_would_have_waited_for_it_for_ever() -> None:
    """What the helper is for: the same work under 3.11's TaskGroup outlives its caller's
    cancellations (this fails the day Python's TaskGroup cancels again; then the helper can go)."""
    swallower = Swallower()
    children: list[asyncio.Task[None]] = []

    async def grouped() -> None:
        async with asyncio.TaskGroup() as group:
            children.append(group.create_task(swallower.run()))

    running = asyncio.create_task(grouped())
    await asyncio.sleep(0.05)
    for _ in range(3):  # as `cancel_and_wait` does: the group cancels its children only once
        running.cancel()
        await asyncio.sleep(0.1)
    assert swallower.swallowed == 1
    assert not swallower.ended
    assert not running.done()
    children[0].cancel()  # clean up: the second cancellation of the child itself ends it
    await asyncio.wait({running}, timeout=1.0)
    assert swallower.ended


async def test_a_failing_child_stops_the_others_and_its_error_is_raised() -> None:
    class LinkLost(Exception):
        pass

    async def failing() -> None:
        await asyncio.sleep(0.05)
        raise LinkLost("the broker went away")

    other = asyncio.Event()

    async def waiting() -> None:
        try:
            await forever()
        finally:
            other.set()

    with pytest.raises(ExceptionGroup) as raised:
        await asyncio.wait_for(side_by_side({"a": failing(), "b": waiting()}, 2.0), 5.0)
    assert [type(e) for e in raised.value.exceptions] == [LinkLost]
    assert other.is_set()


async def test_children_that_return_end_it_quietly() -> None:
    ran: list[str] = []

    async def short(name: str) -> None:
        await asyncio.sleep(0.01)
        ran.append(name)

    await asyncio.wait_for(side_by_side({"a": short("a"), "b": short("b")}, 1.0), 5.0)
    assert sorted(ran) == ["a", "b"]


async def test_the_last_sweep_of_a_stop_ends_work_that_outlived_its_features_stop() -> None:
    tasks = ServiceTasks()
    stubborn = Swallower(times=5)  # more than a feature's own stop budget covers
    async with asyncio.TaskGroup() as group:
        tasks.bind(group)
        tasks.start("stubborn", stubborn.run())
        await asyncio.sleep(0.05)
        assert await tasks.stop_left_over(budget_s=2.0)
        tasks.bind(None)
    assert stubborn.ended
    assert stubborn.swallowed == 5


async def test_the_last_sweep_lets_work_that_is_about_to_end_finish_uncancelled() -> None:
    """As the TaskGroup did: the Home Assistant clean-up, stopped halfway through its clears,
    left entities behind."""
    tasks = ServiceTasks()
    finished: list[str] = []

    async def last_clears() -> None:
        await asyncio.sleep(0.05)
        finished.append("all cleared")

    async with asyncio.TaskGroup() as group:
        tasks.bind(group)
        clean_up = tasks.start("clean-up", last_clears())
        assert await tasks.stop_left_over(budget_s=1.5)
        tasks.bind(None)
    assert finished == ["all cleared"]
    assert not clean_up.cancelled()
