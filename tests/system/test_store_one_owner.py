"""A store has one owner: a second gateway on a store file in use is refused at start (one line
naming the file and the holder's pid, exit code 4) and the first runs on, its events all kept;
without `storage.path` each `gateway_id` has its own file, and an install that has the shared
`events.db` of earlier releases goes on with it."""

from __future__ import annotations

import asyncio
import contextlib
import os
import signal
import sqlite3
from pathlib import Path
from typing import Any

import pytest

from gateway.config import ENV_STATE_DIRECTORY
from gateway.exit_codes import EXIT_STARTUP
from gateway.settings import StoreSettings
from gateway.store import EventStore
from gateway.tasks import ServiceTasks
from tests.support.processes import gateway_process

WAIT_S = 20.0


def gateway_config(gateway_id: str, store: Path, tmp_path: Path) -> dict[str, Any]:
    """A gateway whose line is missing: its drives go offline, which it records as events."""
    return {
        "gateway_id": gateway_id,
        "modbus_tcp": {"host": "127.0.0.1", "port": 0},
        "buses": [{"name": "line1", "port": str(tmp_path / "no-such-tty"), "timeout_ms": 20}],
        "drives": [{"name": "pump1", "bus": "line1", "address": 1}],
        "storage": {"path": str(store)},
    }


def events_in(path: Path) -> list[tuple[int, str]]:
    with contextlib.closing(sqlite3.connect(f"file:{path}?mode=ro", uri=True)) as db:
        return [(row[0], row[1]) for row in db.execute("select id, type from events order by id")]


def test_a_second_gateway_on_a_store_in_use_is_refused_naming_the_file_and_holder(
    tmp_path: Path,
) -> None:
    store = tmp_path / "events.db"
    with gateway_process(gateway_config("cabinet-a", store, tmp_path), tmp_path) as first:
        first.wait_ready(WAIT_S)
        with gateway_process(gateway_config("cabinet-b", store, tmp_path), tmp_path) as second:
            code = second.wait(WAIT_S)
            said = [line for line in second.log.text.splitlines() if "cannot start" in line]
        assert code == EXIT_STARTUP, second.log.text
        assert len(said) == 1, second.log.text
        assert str(store) in said[0]
        assert f"pid {first.process.pid}" in said[0]
        assert "Traceback" not in second.log.text
        assert first.process.poll() is None, first.log.text  # the running one untouched
        first.stop()
        assert first.process.returncode == 0, first.log.text
    assert "UNIQUE constraint" not in first.log.text
    stored = events_in(store)
    ids = [event_id for event_id, _ in stored]
    assert ids == sorted(set(ids))
    # Only the first gateway wrote: its line's loss once, not once per gateway.
    assert [kind for _, kind in stored].count("port_lost") == 1, stored


def test_a_gateway_killed_leaves_nothing_that_keeps_its_next_start_out(tmp_path: Path) -> None:
    store = tmp_path / "events.db"
    settings = gateway_config("cabinet-a", store, tmp_path)
    with gateway_process(settings, tmp_path) as killed:
        killed.wait_ready(WAIT_S)
        killed.signal(signal.SIGKILL)
        killed.wait(WAIT_S)
    with gateway_process(settings, tmp_path) as again:
        again.wait_ready(WAIT_S)  # the kernel let go of the lock with the killed process
        holder = Path(f"{store}.lock").read_text(encoding="ascii").strip()
        assert holder == str(again.process.pid)


def test_two_gateways_without_a_storage_key_each_have_their_own_store(tmp_path: Path) -> None:
    """Two services on one box (two lines, two gateway_ids), neither naming a store: both run."""
    state = Path(os.environ[ENV_STATE_DIRECTORY])  # each test's own (conftest)
    configs = [gateway_config(name, tmp_path / "unused.db", tmp_path) for name in ("a", "b")]
    for each in configs:
        del each["storage"]
    with (
        gateway_process(configs[0], tmp_path) as first,
        gateway_process(configs[1], tmp_path) as second,
    ):
        first.wait_ready(WAIT_S)
        second.wait_ready(WAIT_S)
        assert first.process.poll() is None, first.log.text
        assert second.process.poll() is None, second.log.text
    for name in ("a", "b"):
        assert [kind for _, kind in events_in(state / f"events-{name}.db")].count("port_lost") == 1
    assert not (state / "events.db").exists()


def settings(path: Path, shared: Path) -> StoreSettings:
    return StoreSettings(str(path), 64.0, 90.0, False, 1000, shared_path=str(shared))


async def test_an_install_with_the_shared_store_keeps_it_and_a_second_gateway_starts_its_own(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    shared = tmp_path / "events.db"
    with contextlib.closing(sqlite3.connect(shared)) as db:
        db.execute("create table kept (x)")  # what an earlier release left (any tables)
    own_a, own_b = tmp_path / "events-cabinet-a.db", tmp_path / "events-cabinet-b.db"
    tasks = ServiceTasks()
    async with asyncio.TaskGroup() as group:
        tasks.bind(group)
        first = EventStore(settings(own_a, shared), tasks)
        second = EventStore(settings(own_b, shared), tasks)
        await first.start()
        try:
            await second.start()
            try:
                assert first.status().path == str(shared)
                assert second.status().path == str(own_b)
                first.record("command", {"who": "a"})
                second.record("command", {"who": "b"})
                await first.flush()
                await second.flush()
            finally:
                await second.stop()
        finally:
            await first.stop()
    assert not own_a.exists()
    assert events_in(shared)[-1][1] == "command"
    assert len(events_in(own_b)) == 1
    said = caplog.text
    assert f"keeping {shared}" in said
    assert str(own_a) in said
    assert f"this one starts its own, {own_b}" in said

    # Once a gateway has its own file it keeps to it, whoever starts first next time.
    tasks = ServiceTasks()
    async with asyncio.TaskGroup() as group:
        tasks.bind(group)
        again = EventStore(settings(own_b, shared), tasks)
        await again.start()
        try:
            assert again.status().path == str(own_b)
        finally:
            await again.stop()
