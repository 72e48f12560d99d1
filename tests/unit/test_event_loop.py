"""The service's event loop: a stop that ends even when the loop's default executor doesn't."""

from __future__ import annotations

import asyncio
import logging
import threading
import time
from typing import Any

import pytest

from gateway import event_loop
from gateway.event_loop import bounded_executor_shutdown

uvloop = pytest.importorskip("uvloop")


def test_a_stop_ends_though_the_executor_s_shutdown_never_wakes_the_loop(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """uvloop 0.23's executor shutdown waits for its helper thread's wake-up with no timer of
    its own, and under heavy load that wake-up was seen never to come (the thread gone, the
    loop in epoll_wait): the stop hung. Here the wake-up is lost on purpose; the service's loop
    gives up after its bound, says so, and the stop goes on."""
    monkeypatch.setattr(event_loop, "EXECUTOR_SHUTDOWN_S", 0.5)
    loses_its_wake_up = bounded_executor_shutdown(_LosesTheShutdownsWakeUp)
    names: list[str] = []

    async def main() -> None:
        await asyncio.to_thread(time.sleep, 0.01)  # the default executor, with a thread
        names.append(event_loop.running_loop_name())

    started = time.monotonic()
    with (
        caplog.at_level(logging.WARNING, logger="gateway.event_loop"),
        asyncio.Runner(loop_factory=loses_its_wake_up) as runner,
    ):
        runner.run(main())
    assert time.monotonic() - started < 3
    assert "did not shut down in 0.5 s" in caplog.text
    assert names == ["uvloop"]  # a subclass of uvloop's loop is uvloop still, for the metrics


class _LosesTheShutdownsWakeUp(uvloop.Loop):  # type: ignore[misc,name-defined]
    """uvloop's loop, but the executor shutdown's wake-up from its helper thread never comes."""

    def call_soon_threadsafe(self, callback: Any, *args: Any, context: Any = None) -> Any:
        if getattr(
            callback, "__name__", ""
        ) == "set_result" and threading.current_thread().name.endswith("(_do_shutdown)"):
            return None
        return super().call_soon_threadsafe(callback, *args, context=context)


def test_a_loop_whose_executor_ends_stops_at_once_and_quietly(
    caplog: pytest.LogCaptureFixture,
) -> None:
    async def main() -> None:
        await asyncio.to_thread(time.sleep, 0.01)

    started = time.monotonic()
    with (
        caplog.at_level(logging.WARNING, logger="gateway.event_loop"),
        asyncio.Runner(loop_factory=bounded_executor_shutdown(uvloop.Loop)) as runner,
    ):
        runner.run(main())
    assert time.monotonic() - started < 2
    assert caplog.text == ""
