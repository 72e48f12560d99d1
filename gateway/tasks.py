"""Background tasks: run under the service's TaskGroup, and stopped for sure within a budget."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Coroutine
from typing import Any

from gateway.errors import FeatureFailed

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


class ServiceTasks:
    """Where every feature runs its background work: the application's one TaskGroup.

    Handed to each feature when it is built; the application binds it to its TaskGroup while it
    runs. Work that dies of a bug stops the whole service, saying why (`FeatureFailed`).
    """

    def __init__(self) -> None:
        self._group: asyncio.TaskGroup | None = None

    def bind(self, group: asyncio.TaskGroup | None) -> None:
        self._group = group

    def start(self, name: str, work: Coroutine[Any, Any, None]) -> asyncio.Task[None]:
        if self._group is None:
            work.close()
            raise RuntimeError(f"{name}: the service is not running")
        return self._group.create_task(_failing_loudly(name, work), name=name)


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
