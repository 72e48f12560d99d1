"""The store's schema across releases: a store of every earlier schema is migrated on start and
keeps what it holds; a store of a newer release is refused (one line, the failed start's exit
code) and left as it is; a store lacking a column it should have is kept out of use, loudly.

The earlier schemas are recorded as their releases wrote them (tests/fixtures/store_schema_N.sql),
not made by today's code: a migration edited after its release shows here.
"""

from __future__ import annotations

import contextlib
import sqlite3
import time
from pathlib import Path

import pytest

from gateway.config import StorageConfig
from gateway.exit_codes import EXIT_STARTUP
from gateway.store import schema
from gateway.store.status import StoreState
from tests.support import free_port
from tests.support.mqtt_setup import simulated_line
from tests.support.processes import gateway_process
from tests.support.store import running_store

FIXTURES = Path(__file__).parents[1] / "fixtures"
RELEASED = {
    1: FIXTURES / "store_schema_1.sql",
    2: FIXTURES / "store_schema_2.sql",
    3: FIXTURES / "store_schema_3.sql",
}
"""Every schema a release wrote, but the current one."""


def store_from(sql: Path, path: Path, version: int | None = None) -> None:
    """A store file as an earlier release left it (`version`: marked otherwise)."""
    with contextlib.closing(sqlite3.connect(path, isolation_level=None)) as db:
        db.execute("PRAGMA journal_mode = WAL")
        db.executescript(sql.read_text(encoding="utf-8"))
        if version is not None:
            db.execute(f"PRAGMA user_version = {version}")


def user_version(path: Path) -> int:
    with contextlib.closing(sqlite3.connect(f"file:{path}?mode=ro", uri=True)) as db:
        value: int = db.execute("PRAGMA user_version").fetchone()[0]
        return value


def test_every_earlier_schema_has_its_recorded_store() -> None:
    # A new migration needs the store of the schema before it in tests/fixtures.
    assert set(RELEASED) == set(range(1, schema.LATEST))


@pytest.mark.parametrize("version", sorted(RELEASED))
async def test_a_store_of_an_earlier_release_is_migrated_keeping_what_it_holds(
    tmp_path: Path, version: int
) -> None:
    path = tmp_path / "events.db"
    store_from(RELEASED[version], path)
    config = StorageConfig(path=str(path), max_age_days=36500)  # the fixture's events are old
    async with running_store(config) as store:
        assert store.status().state is StoreState.WRITING
        waiting = await store.undelivered(10)
        assert [e.id for e in waiting] == [3, 5]  # what the broker didn't have still waits
        assert waiting[0].data["fault_name"] == "OL1"
        open_fault = (await store.fault_history("fan2", 5))[0]
        assert (open_fault.code, open_fault.cleared) == (9, None)
        assert (await store.fault_history("pump1", 5))[0].cleared == 1763000060.0
        store.record("command", {"n": 1})
        store.keep_tally("writes", "modbus_writes", {"writes": 3}, at=time.time())
        await store.flush()
        assert (await store.recent_events(1))[0].id == 6  # ids go on from the old file's
    assert user_version(path) == schema.LATEST
    async with running_store(config) as store:
        newest = (await store.recent_events(1))[0]
    assert (newest.type, newest.data) == ("modbus_writes", {"writes": 3})  # the new table works


def test_a_store_of_a_newer_release_is_refused_and_left_as_it_is(tmp_path: Path) -> None:
    path = tmp_path / "events.db"
    newer = schema.LATEST + 5
    store_from(RELEASED[1], path, version=newer)
    with simulated_line((1,)) as line:
        config = {
            "modbus_tcp": {"host": "127.0.0.1", "port": free_port()},
            "buses": [{"name": "line1", "port": line.path, "baudrate": 115200, "parity": "E"}],
            "drives": [{"bus": "line1", "name": "pump1", "address": 1, "model": "gd350"}],
            "storage": {"path": str(path)},
        }
        with gateway_process(config, tmp_path) as gateway:
            assert gateway.wait(20) == EXIT_STARTUP
            log = gateway.log.text
    said = [line for line in log.splitlines() if "newer release" in line]
    assert len(said) == 1, log
    assert f"store schema {newer}" in said[0]
    assert f"1 to {schema.LATEST}" in said[0]
    assert str(path) in said[0]
    assert "Traceback" not in log
    assert user_version(path) == newer  # never re-marked


def test_a_store_of_a_newer_release_is_not_touched_not_even_switched_to_wal(
    tmp_path: Path,
) -> None:
    """A newer release that keeps its store in another journal mode finds it as it left it: the
    version is checked before the switch to WAL mode (a write to the file's header)."""
    path = tmp_path / "events.db"
    newer = schema.LATEST + 1
    with contextlib.closing(sqlite3.connect(path, isolation_level=None)) as db:
        db.executescript(RELEASED[1].read_text(encoding="utf-8"))
        db.execute(f"PRAGMA user_version = {newer}")
    before = path.read_bytes()
    config = {
        "modbus_tcp": {"host": "127.0.0.1", "port": 0},
        "buses": [{"name": "line1", "port": str(tmp_path / "no-such-tty"), "timeout_ms": 20}],
        "drives": [{"bus": "line1", "name": "pump1", "address": 1}],
        "storage": {"path": str(path)},
    }
    with gateway_process(config, tmp_path) as gateway:
        assert gateway.wait(20) == EXIT_STARTUP, gateway.log.text
    assert path.read_bytes() == before  # header (journal mode, version) and pages alike
    assert not Path(f"{path}-wal").exists()
    with contextlib.closing(sqlite3.connect(f"file:{path}?mode=ro", uri=True)) as db:
        assert db.execute("PRAGMA journal_mode").fetchone()[0] == "delete"


async def test_a_store_missing_a_column_is_kept_out_of_use_and_says_which(tmp_path: Path) -> None:
    path = tmp_path / "events.db"
    sql = (FIXTURES / "store_schema_1.sql").read_text(encoding="utf-8")
    damaged = tmp_path / "damaged.sql"
    damaged.write_text(
        sql.replace(",\n    delivered INTEGER NOT NULL DEFAULT 0", "")
        .replace(" WHERE delivered = 0", "")
        .replace(", 1);", ");")
        .replace(", 0);", ");"),
        encoding="utf-8",
    )
    store_from(damaged, path)
    async with running_store(StorageConfig(path=str(path))) as store:
        status = store.status()
        store.record("command", {"n": 1})
        await store.flush()
        assert [e.data for e in await store.undelivered(10)] == [{"n": 1}]  # in memory
    assert status.state is StoreState.MEMORY_ONLY
    assert status.reason is not None
    assert "table events has no column delivered" in status.reason
    assert str(path) in status.reason
