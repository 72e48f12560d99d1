"""Background tasks: run under the service's TaskGroup, and stopped for sure within a budget."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Coroutine, Mapping
from typing import Any

from gateway.errors import FeatureFailed

log = logging.getLogger(__name__)

RETRY_S = 0.1
GRACE_S = 0.5
"""At most this long after the first cancellation before cancelling again."""
FINISH_S = 0.3
"""At a stop's last sweep: how long left-over work is given to end by itself, uncancelled."""


async def cancel_and_wait(task: asyncio.Task[None], budget_s: float) -> bool:
    """Cancel `task` and wait for it to end; True if it did within `budget_s`.

    One cancel is not always enough on Python 3.11: `asyncio.wait_for` swallows a cancellation
    that arrives as its inner future completes (CPython gh-86296, fixed in 3.12), and libraries
    we await (aiomqtt's publish and subscribe) use it. So cancel again until the task is done
    (after a grace for its clean-up: `_cancel_until_done`).
    """
    if not await _cancel_until_done([task], budget_s):
        return False
    with contextlib.suppress(asyncio.CancelledError):
        exception = task.exception()
        if exception is not None:
            log.error("task %s ended with %r", task.get_name(), exception)
    return True


async def _cancel_until_done(tasks: list[asyncio.Task[None]], budget_s: float) -> bool:
    """Cancel `tasks` once and give them half the budget to end (clean-up code runs then: an
    MQTT client's disconnect, interrupted by a second cancellation, would leave its socket
    behind); then cancel what is left again and again, for what swallowed the first."""
    started = time.monotonic()
    deadline = started + budget_s
    again_at = started + min(budget_s / 2, GRACE_S)
    for task in tasks:
        task.cancel()
    while alive := [task for task in tasks if not task.done()]:
        now = time.monotonic()
        remaining = deadline - now
        if remaining <= 0:
            names = ", ".join(task.get_name() for task in alive)
            log.error("task %s did not stop within %.1f s", names, budget_s)
            return False
        if now >= again_at:
            for task in alive:
                task.cancel()
        wait_s = RETRY_S if now >= again_at else again_at - now
        await asyncio.wait(alive, timeout=min(wait_s, remaining))
    return True


async def side_by_side(work: Mapping[str, Coroutine[Any, Any, None]], budget_s: float) -> None:
    """Run `work` (coroutines by task name) concurrently until each has returned, one has failed, or
    the caller is cancelled; then cancel the others (`_cancel_until_done`) and re-raise.

    Why not a TaskGroup: Python 3.11's cancels its children once. A child whose cancellation
    aiomqtt's `wait_for` swallowed (see `cancel_and_wait`) went on publishing, the group waited
    for it, and so did the service's stop: for ever. Here a child still running after a grace
    for its clean-up is cancelled again until it ends, for at most `budget_s`; a caller
    cancelled again meanwhile leaves at once (the shield), the children's cancelling goes on
    without it.
    """
    tasks = [asyncio.create_task(coro, name=name) for name, coro in work.items()]
    try:
        await asyncio.wait(tasks, return_when=asyncio.FIRST_EXCEPTION)
    finally:
        await asyncio.shield(_cancel_until_done(tasks, budget_s))
    failures = [
        failure
        for task in tasks
        if not task.cancelled() and (failure := task.exception()) is not None
    ]
    if failures:
        raise BaseExceptionGroup("side by side", failures)


class ServiceTasks:
    """Where every feature runs its background work: the application's one TaskGroup.

    Handed to each feature when it is built; the application binds it to its TaskGroup while it
    runs. Work that dies of a bug stops the whole service, saying why (`FeatureFailed`).
    """

    def __init__(self) -> None:
        self._group: asyncio.TaskGroup | None = None
        self._running: set[asyncio.Task[None]] = set()

    def bind(self, group: asyncio.TaskGroup | None) -> None:
        self._group = group

    def start(self, name: str, work: Coroutine[Any, Any, None]) -> asyncio.Task[None]:
        if self._group is None:
            work.close()
            raise RuntimeError(f"{name}: the service is not running")
        task = self._group.create_task(_failing_loudly(name, work), name=name)
        self._running.add(task)
        task.add_done_callback(self._running.discard)
        return task

    async def stop_left_over(self, budget_s: float) -> bool:
        """The last sweep of a stop: work no feature stops (the Home Assistant clean-up) first
        gets `FINISH_S` to end by itself, as the TaskGroup let it before; then what is left, and
        work a feature's stop left running (its cancellation swallowed once too often), is
        cancelled until it ends, for at most `budget_s`. Without the sweep the TaskGroup, and so
        the service's exit, would wait for such work for ever."""
        running = list(self._running)
        if running:
            await asyncio.wait(running, timeout=FINISH_S)
        left = [task for task in running if not task.done()]
        return await _cancel_until_done(left, budget_s)


async def _failing_loudly(name: str, work: Coroutine[Any, Any, None]) -> None:
    try:
        await work
    except Exception as exc:
        log.critical("%s died", name, exc_info=exc)
        raise FeatureFailed(f"{name} died: {_first(exc)!r}") from exc


def _first(exc: BaseException) -> BaseException:
    """The exception itself, not the group a TaskGroup wrapped it in."""
    while isinstance(exc, BaseExceptionGroup) and len(exc.exceptions) == 1:
        exc = exc.exceptions[0]
    return exc
