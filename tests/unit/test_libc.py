"""libc reached without a child process: a child forked while a serial port is open holds the
port's exclusive lock until it execs, and the simulated drives' thread looking libc up while the
gateway opened its port left the gateway with "Could not exclusively lock port" (a flaky test,
then, in CI)."""

from __future__ import annotations

import sys
from collections.abc import Iterator

import pytest

from gateway import timerfd
from gateway.libc import process_libc
from gateway.timer_slack import tighten_timer_slack

_spawned: list[str] | None = None
"""The processes started while a test records (the audit hook can't be removed: it records
only while this is a list)."""


def _record_spawns(event: str, args: tuple[object, ...]) -> None:
    if _spawned is not None and event in ("subprocess.Popen", "os.posix_spawn", "os.fork"):
        _spawned.append(f"{event} {args[:2]!r}")


sys.addaudithook(_record_spawns)


@pytest.fixture
def spawned() -> Iterator[list[str]]:
    global _spawned
    process_libc.cache_clear()  # looked up afresh, as in a new process
    timerfd.libc.cache_clear()
    _spawned = []
    try:
        yield _spawned
    finally:
        _spawned = None


def test_the_timer_slack_and_timerfd_reach_libc_without_starting_a_process(
    spawned: list[str],
) -> None:
    assert tighten_timer_slack()  # the kernel took it: prctl was found and called
    timer = timerfd.DeadlineTimer()
    try:
        assert timer.fd >= 0
    finally:
        timer.close()
    assert spawned == []
