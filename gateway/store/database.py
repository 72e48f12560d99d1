"""The store's SQLite database: one file in WAL mode, bounded in size and age.

Used only from the store's own thread (`gateway.store.events`): every call here blocks on the
disk. Tables:

    events   id (AUTOINCREMENT: never reused, so strictly increasing across restarts and
             trims), type, time, drive, data (JSON), delivered (0 until the broker has it)
    faults   one row per fault of a drive: code, name, description, raised, cleared, and the
             snapshot of its running values when it was raised

Bounds, checked after every write: past `max_bytes` in use, the oldest events go first (then, with
no event left, the oldest faults); rows older than `max_age_s` go at the hourly expiry. Events
that go before the broker had them are counted as dropped; the caller logs them. Freed pages are
given back to the file system (incremental vacuum), so the file itself stays within the bound;
the write-ahead log beside it is checkpointed and truncated at a quarter of the bound.

`synchronous=FULL`: a committed event survives a power cut, not only a killed process.
"""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

from gateway.errors import StoreError
from gateway.store.records import EventType, FaultRecord, NewEvent, StoredEvent

MEMORY: Final = ":memory:"
SCHEMA_VERSION: Final = 1
TRIM_FRACTION: Final = 16
"""Past the size bound, this fraction of the events (at least one) goes per step."""
MIN_WAL_PAGES: Final = 16

SCHEMA: Final = """
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
"""


@dataclass(frozen=True, slots=True)
class Appended:
    events: list[StoredEvent]
    dropped: int
    """Events removed by the size bound before the broker had them."""


class EventDatabase:
    def __init__(self, path: str, max_bytes: int, max_age_s: float, forwarding: bool) -> None:
        self.path = path
        self.max_bytes = max_bytes
        self.max_age_s = max_age_s
        self.forwarding = forwarding
        """False without MQTT: events are kept for their history, nobody waits for them."""
        self._db: sqlite3.Connection | None = None

    @property
    def persistent(self) -> bool:
        return self.path != MEMORY

    # -- opening and closing -------------------------------------------------------------------

    def open(self) -> None:
        try:
            if self.persistent:
                Path(self.path).parent.mkdir(parents=True, exist_ok=True)
            db = sqlite3.connect(self.path, isolation_level=None)
        except (OSError, sqlite3.Error) as exc:
            raise StoreError(f"{self.path}: {exc}") from exc
        try:
            self._set_up(db)
        except sqlite3.Error as exc:
            db.close()
            raise StoreError(f"{self.path}: {exc}") from exc
        self._db = db

    def _set_up(self, db: sqlite3.Connection) -> None:
        new = db.execute("PRAGMA user_version").fetchone()[0] == 0
        if new:
            # Only before the first table: lets deletes give pages back to the file system.
            db.execute("PRAGMA auto_vacuum = INCREMENTAL")
        if self.persistent:
            mode = db.execute("PRAGMA journal_mode = WAL").fetchone()[0]
            if str(mode).lower() != "wal":
                raise sqlite3.OperationalError(f"WAL mode refused (journal mode {mode})")
        db.execute("PRAGMA synchronous = FULL")
        page_size = db.execute("PRAGMA page_size").fetchone()[0]
        wal_pages = max(MIN_WAL_PAGES, min(1000, self.max_bytes // page_size // 4))
        db.execute(f"PRAGMA wal_autocheckpoint = {wal_pages}")
        db.execute(f"PRAGMA journal_size_limit = {wal_pages * page_size}")
        db.executescript(SCHEMA)
        db.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")

    def close(self) -> None:
        if self._db is not None:
            self._db.close()
            self._db = None

    @property
    def db(self) -> sqlite3.Connection:
        if self._db is None:
            raise StoreError(f"{self.path}: not open")
        return self._db

    # -- writing -------------------------------------------------------------------------------

    def append(self, events: Sequence[NewEvent]) -> Appended:
        """Store `events` in one transaction (with their faults); then hold the size bound."""
        db = self.db
        stored = []
        delivered = 0 if self.forwarding else 1
        with _transaction(db):
            for event in events:
                cursor = db.execute(
                    "INSERT INTO events (type, time, drive, data, delivered) "
                    "VALUES (?, ?, ?, ?, ?)",
                    (event.type, event.time, event.drive, _dump(event.data), delivered),
                )
                assert cursor.lastrowid is not None
                stored.append(StoredEvent(cursor.lastrowid, event.type, event.time, event.data))
                self._fault_history(event)
        return Appended(stored, self._hold_size())

    def close_open_faults(self, drive: str, at: float) -> int:
        """The drive shows no fault: a fault still open in its history cleared while the gateway
        wasn't looking (it was down); closed at `at`, the first time it was seen clear."""
        with _transaction(self.db):
            cursor = self.db.execute(
                "UPDATE faults SET cleared = ? WHERE drive = ? AND cleared IS NULL", (at, drive)
            )
        return cursor.rowcount

    def mark_delivered(self, ids: Iterable[int]) -> None:
        with _transaction(self.db):
            self.db.executemany("UPDATE events SET delivered = 1 WHERE id = ?", ((i,) for i in ids))

    def expire(self, now: float) -> int:
        """Remove what is older than `max_age_s`; how many undelivered events went with it."""
        cutoff = now - self.max_age_s
        db = self.db
        with _transaction(db):
            undelivered = "SELECT count(*) FROM events WHERE delivered = 0 AND time < ?"
            dropped = _count(db, undelivered, cutoff)
            db.execute("DELETE FROM events WHERE time < ?", (cutoff,))
            db.execute("DELETE FROM faults WHERE raised < ? AND cleared IS NOT NULL", (cutoff,))
        db.execute("PRAGMA incremental_vacuum").fetchall()  # one page per step
        return dropped

    def _fault_history(self, event: NewEvent) -> None:
        if event.drive is None:
            return
        code = event.data.get("fault_code")
        if not isinstance(code, int):
            return
        open_row = self.db.execute(
            "SELECT id, code FROM faults WHERE drive = ? AND cleared IS NULL "
            "ORDER BY id DESC LIMIT 1",
            (event.drive,),
        ).fetchone()
        if event.type == EventType.FAULT_RAISED:
            if open_row is not None and open_row[1] == code:
                return  # seen again after a restart: the same fault, still raised
            self.db.execute(
                "INSERT INTO faults (drive, code, name, description, raised, snapshot) "
                "VALUES (?, ?, ?, ?, ?, ?)",
                (
                    event.drive,
                    code,
                    str(event.data.get("fault_name", code)),
                    str(event.data.get("fault_description", "")),
                    event.time,
                    _dump(event.snapshot or {}),
                ),
            )
        elif event.type == EventType.FAULT_CLEARED and open_row is not None:
            self.db.execute("UPDATE faults SET cleared = ? WHERE id = ?", (event.time, open_row[0]))

    def _hold_size(self) -> int:
        """Trim the oldest rows until the file is within `max_bytes`; undelivered dropped."""
        db = self.db
        dropped = 0
        while self.file_bytes() > self.max_bytes:
            free = _count(db, "PRAGMA freelist_count")
            if free:
                # Pages freed by the last trim (or an expiry) go back to the file system first.
                db.execute("PRAGMA incremental_vacuum").fetchall()  # one page per step
                if _count(db, "PRAGMA freelist_count") < free:
                    continue
            oldest, newest = db.execute("SELECT min(id), max(id) FROM events").fetchone()
            with _transaction(db):
                if oldest is not None:
                    below = oldest + max(1, (newest - oldest + 1) // TRIM_FRACTION)
                    dropped += _count(
                        db, "SELECT count(*) FROM events WHERE delivered = 0 AND id < ?", below
                    )
                    db.execute("DELETE FROM events WHERE id < ?", (below,))
                elif db.execute("SELECT 1 FROM faults LIMIT 1").fetchone() is not None:
                    db.execute("DELETE FROM faults WHERE id = (SELECT min(id) FROM faults)")
                else:
                    break  # nothing left to give: the bound is smaller than an empty store
        return dropped

    # -- reading -------------------------------------------------------------------------------

    def undelivered(self, after_id: int, limit: int) -> list[StoredEvent]:
        rows = self.db.execute(
            "SELECT id, type, time, data FROM events WHERE delivered = 0 AND id > ? "
            "ORDER BY id LIMIT ?",
            (after_id, limit),
        ).fetchall()
        return [_event(row) for row in rows]

    def undelivered_count(self) -> int:
        return _count(self.db, "SELECT count(*) FROM events WHERE delivered = 0")

    def recent(self, limit: int, drive: str | None) -> list[StoredEvent]:
        """The newest `limit` events (of `drive`), newest first."""
        if drive is None:
            sql, args = "SELECT id, type, time, data FROM events ORDER BY id DESC LIMIT ?", (limit,)
        else:
            sql = "SELECT id, type, time, data FROM events WHERE drive = ? ORDER BY id DESC LIMIT ?"
            args = (drive, limit)  # type: ignore[assignment]
        return [_event(row) for row in self.db.execute(sql, args).fetchall()]

    def faults(self, drive: str, limit: int) -> list[FaultRecord]:
        """The newest `limit` faults of `drive`, newest first."""
        rows = self.db.execute(
            "SELECT drive, code, name, description, raised, cleared, snapshot FROM faults "
            "WHERE drive = ? ORDER BY id DESC LIMIT ?",
            (drive, limit),
        ).fetchall()
        return [
            FaultRecord(row[0], row[1], row[2], row[3], row[4], row[5], json.loads(row[6]))
            for row in rows
        ]

    def file_bytes(self) -> int:
        """The database's size (what the file holds once the WAL is checkpointed)."""
        return _count(self.db, "PRAGMA page_count") * _count(self.db, "PRAGMA page_size")


class _transaction:
    """BEGIN IMMEDIATE ... COMMIT, or ROLLBACK on an error (autocommit connection)."""

    def __init__(self, db: sqlite3.Connection) -> None:
        self.db = db

    def __enter__(self) -> None:
        self.db.execute("BEGIN IMMEDIATE")

    def __exit__(self, kind: type[BaseException] | None, *rest: object) -> None:
        self.db.execute("COMMIT" if kind is None else "ROLLBACK")


def _count(db: sqlite3.Connection, sql: str, *args: Any) -> int:
    value: int = db.execute(sql, args).fetchone()[0]
    return value


def _event(row: tuple[Any, ...]) -> StoredEvent:
    return StoredEvent(row[0], row[1], row[2], json.loads(row[3]))


def _dump(value: object) -> str:
    return json.dumps(value, separators=(",", ":"), sort_keys=False)
