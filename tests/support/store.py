"""The event store on a real SQLite file, running in a TaskGroup of its own as the service runs
it."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator

from gateway.config import StorageConfig
from gateway.settings import StoreSettings
from gateway.store import EventStore
from gateway.tasks import ServiceTasks


@contextlib.asynccontextmanager
async def running_store(
    config: StorageConfig, forwarding: bool = True
) -> AsyncIterator[EventStore]:
    tasks = ServiceTasks()
    async with asyncio.TaskGroup() as group:
        tasks.bind(group)
        settings = StoreSettings(
            config.resolved_path("test"),
            config.max_mb,
            config.max_age_days,
            forwarding,
            100_000,
            outage_buffer_mb=config.outage_buffer if forwarding else 0.0,
            outage_buffer_hours=config.outage_buffer_hours,
        )
        store = EventStore(settings, tasks)
        await store.start()
        try:
            yield store
        finally:
            await store.stop()
