"""Incoming messages handled off the receive loop: in order within a lane, lanes in parallel.

The receive loop must never wait for a drive: one slow message (a `/get` behind a busy line, a
drive that times out) would hold back every message after it, a `stop` for another drive too.
So each message becomes a job in a lane, and each lane with work has one task that runs its jobs
one after the other. The bridge gives every drive its own lane for commands (they execute in the
order they arrived, as the sender meant them; a read after a write sees the write) and another
for `/get`, so a refresh never holds back a `stop` to the same drive either.

Bounded: the lanes are a fixed set (per drive, plus a few of the bridge's), so are their tasks,
and a lane holds at most `max_waiting` jobs not started yet. Past that `submit` says no and the
caller answers `busy`: a flood on one drive neither grows memory nor delays the others.
"""

from __future__ import annotations

import asyncio
import logging
from collections import deque
from collections.abc import Awaitable, Callable

from gateway.tasks import ServiceTasks, cancel_and_wait

log = logging.getLogger(__name__)

Job = Callable[[], Awaitable[None]]


class Lanes:
    def __init__(self, max_waiting: int, tasks: ServiceTasks | None = None) -> None:
        """`tasks`: the service's, so a lane that dies of a bug stops the service; without
        (lanes used on their own), plain tasks."""
        self.max_waiting = max_waiting
        self._service_tasks = tasks
        self.dropped = 0
        """Jobs forgotten before they started (their connection was lost, or stop)."""
        self._waiting: dict[str, deque[Job]] = {}
        self._workers: dict[str, asyncio.Task[None]] = {}
        self._tasks: set[asyncio.Task[None]] = set()
        """Every worker until it has ended, also one replaced in `_workers` (see `_run`)."""

    def submit(self, lane: str, job: Job) -> bool:
        """Queue `job` behind the others of `lane`; False (and nothing queued) when it is full."""
        waiting = self._waiting.setdefault(lane, deque())
        if len(waiting) >= self.max_waiting:
            return False
        waiting.append(job)
        if lane not in self._workers:
            name = f"mqtt:lane:{lane}"
            work = self._run(lane, waiting)
            if self._service_tasks is not None:
                task = self._service_tasks.start(name, work)
            else:
                task = asyncio.create_task(work, name=name)
            self._workers[lane] = task
            self._tasks.add(task)
            task.add_done_callback(self._tasks.discard)
        return True

    def waiting(self, lane: str) -> int:
        """Jobs of `lane` not started yet."""
        return len(self._waiting.get(lane, ()))

    @property
    def running(self) -> int:
        """Lanes with a task (running a job, or about to)."""
        return len(self._workers)

    def drop_waiting(self) -> None:
        """Forget every job not started yet; the running ones finish."""
        for waiting in self._waiting.values():
            self.dropped += len(waiting)
            waiting.clear()  # in place: each worker holds its lane's deque

    async def close(self, budget_s: float) -> None:
        """Forget what waits, cancel what runs, and wait (at most `budget_s`) for each to end."""
        self.drop_waiting()
        tasks = list(self._tasks)
        if tasks:
            await asyncio.gather(*(cancel_and_wait(task, budget_s) for task in tasks))

    async def _run(self, lane: str, waiting: deque[Job]) -> None:
        try:
            while waiting:
                job = waiting.popleft()
                try:
                    await job()
                except Exception:
                    # Jobs answer their own errors; this is the last guard that keeps the lane's
                    # later jobs from being stranded by a bug in one.
                    log.exception("MQTT: a job in lane %s failed", lane)
        finally:
            # No await between finding the deque empty and leaving the map: a job submitted
            # from now on starts a new worker instead of waiting for this one that has ended.
            if self._workers.get(lane) is asyncio.current_task():
                del self._workers[lane]
