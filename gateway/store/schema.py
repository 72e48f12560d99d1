"""The store's tables, as numbered migrations: the file's `user_version` says how many ran.

A change to the tables is a new migration at the end of `MIGRATIONS`, never an edit of one that
was released (stores of that release ran it already). On open, the migrations after the file's
version run in order, each in one transaction with its version, so a crash between two leaves a
file that the next start carries on from. A file of a newer release (a version past the last
migration here) is refused: this release doesn't know what that one keeps there, and marking
the file with an older version would have the newer release skip its own migrations on return.

    1  events and faults, with their indexes (the first store)
    2  tallies: counts still growing (a minute's SCADA writes), kept as they grow so that a
       killed gateway loses none; each becomes an event once complete
    3  history: polled values, one row per drive and step (`gateway.store.history`);
       config_versions: each configuration applied from the console, with who and when
    4  counters: numbers that count on across restarts (the Sparkplug edge node's bdSeq);
       outage: running values polled while the broker was away, until delivered
       (`gateway.store.outage_rows`)
"""

from __future__ import annotations

import sqlite3
from typing import Final

from gateway.errors import StoreError, StoreRefused

MIGRATIONS: Final[tuple[str, ...]] = (
    # 1: the first store.
    """
    CREATE TABLE IF NOT EXISTS events (
        id INTEGER PRIMARY KEY AUTOINCREMENT,
        type TEXT NOT NULL,
        time REAL NOT NULL,
        drive TEXT,
        data TEXT NOT NULL,
        delivered INTEGER NOT NULL DEFAULT 0
    );
    CREATE INDEX IF NOT EXISTS events_undelivered ON events (id) WHERE delivered = 0;
    CREATE INDEX IF NOT EXISTS events_by_drive ON events (drive, id);
    CREATE TABLE IF NOT EXISTS faults (
        id INTEGER PRIMARY KEY AUTOINCREMENT,
        drive TEXT NOT NULL,
        code INTEGER NOT NULL,
        name TEXT NOT NULL,
        description TEXT NOT NULL,
        raised REAL NOT NULL,
        cleared REAL,
        snapshot TEXT NOT NULL
    );
    CREATE INDEX IF NOT EXISTS faults_by_drive ON faults (drive, id);
    """,
    # 2: tallies. IF NOT EXISTS: a release before migrations re-marked the file 1 and left the
    # table; the next upgrade runs this again.
    """
    CREATE TABLE IF NOT EXISTS tallies (
        key TEXT PRIMARY KEY,
        type TEXT NOT NULL,
        time REAL NOT NULL,
        drive TEXT,
        data TEXT NOT NULL
    );
    """,
    # 3: the history of polled values, and the configuration's versions.
    """
    CREATE TABLE IF NOT EXISTS history (
        id INTEGER PRIMARY KEY,
        drive TEXT NOT NULL,
        time REAL NOT NULL,
        data TEXT NOT NULL
    );
    CREATE UNIQUE INDEX IF NOT EXISTS history_by_drive ON history (drive, time);
    CREATE TABLE IF NOT EXISTS config_versions (
        id INTEGER PRIMARY KEY AUTOINCREMENT,
        time REAL NOT NULL,
        user TEXT NOT NULL,
        text TEXT NOT NULL,
        note TEXT NOT NULL
    );
    """,
    # 4: counters that go on across restarts; the outage buffer.
    """
    CREATE TABLE IF NOT EXISTS counters (
        key TEXT PRIMARY KEY,
        value INTEGER NOT NULL
    );
    CREATE TABLE IF NOT EXISTS outage (
        id INTEGER PRIMARY KEY AUTOINCREMENT,
        route TEXT NOT NULL,
        drive TEXT NOT NULL,
        time REAL NOT NULL,
        data TEXT NOT NULL
    );
    CREATE INDEX IF NOT EXISTS outage_by_route ON outage (route, id);
    """,
)
LATEST: Final = len(MIGRATIONS)

COLUMNS: Final[dict[str, frozenset[str]]] = {
    "events": frozenset({"id", "type", "time", "drive", "data", "delivered"}),
    "faults": frozenset(
        {"id", "drive", "code", "name", "description", "raised", "cleared", "snapshot"}
    ),
    "tallies": frozenset({"key", "type", "time", "drive", "data"}),
    "history": frozenset({"id", "drive", "time", "data"}),
    "config_versions": frozenset({"id", "time", "user", "text", "note"}),
    "counters": frozenset({"key", "value"}),
    "outage": frozenset({"id", "route", "drive", "time", "data"}),
}
"""What the code reads and writes, after the last migration: checked at every open."""


def version(db: sqlite3.Connection) -> int:
    value: int = db.execute("PRAGMA user_version").fetchone()[0]
    return value


def refuse_newer(db: sqlite3.Connection, path: str) -> None:
    """`StoreRefused` for a file of a newer release; reads only (the caller checks this before
    anything that writes to the file, the switch to WAL mode included)."""
    found = version(db)
    if found > LATEST:
        raise StoreRefused(
            f"storage.path {path}: written by a newer release (store schema {found}; this "
            f"release knows 1 to {LATEST}); run that release, or restore a backup of this one"
        )


def migrate(db: sqlite3.Connection, path: str) -> list[int]:
    """Bring the file at `path` to `LATEST`; the migrations that ran. Raises `StoreRefused` for a
    file of a newer release, `StoreError` for one that lacks what the code needs."""
    refuse_newer(db, path)
    found = version(db)
    ran = []
    for number in range(found + 1, LATEST + 1):
        db.execute("BEGIN IMMEDIATE")
        try:
            for statement in _statements(MIGRATIONS[number - 1]):
                db.execute(statement)
            db.execute(f"PRAGMA user_version = {number}")
        except BaseException:
            db.execute("ROLLBACK")
            raise
        db.execute("COMMIT")
        ran.append(number)
    _check_columns(db, path)
    return ran


def _check_columns(db: sqlite3.Connection, path: str) -> None:
    for table, wanted in COLUMNS.items():
        found = {row[1] for row in db.execute(f"PRAGMA table_info({table})")}
        missing = sorted(wanted - found)
        if missing:
            raise StoreError(
                f"{path}: table {table} has no column {', '.join(missing)} though the file "
                f"says store schema {version(db)}: not a file this gateway wrote"
            )


def _statements(script: str) -> list[str]:
    """`script` one statement at a time (`executescript` would commit the transaction)."""
    return [part.strip() for part in script.split(";") if part.strip()]
