"""The store's SQLite database: one file in WAL mode, bounded in size and age, one owner.

Used only from the store's own thread (`gateway.store.events`): every call here blocks on the
disk. Opened only under the file's lock (`gateway.store.owner`): a second gateway on the same
file is refused rather than writing over the first's events. Tables (their migrations in
`gateway.store.schema`):

    events   id (given by the store when the event is recorded, never reused: strictly
             increasing across restarts and trims), type, time, drive, data (JSON), delivered
             (0 until the broker has it)
    faults   one row per fault of a drive: code, name, description, raised, cleared, and the
             snapshot of its running values when it was raised
    tallies  counts still growing (a minute's SCADA writes), one row each, rewritten as they
             grow; each becomes an event once complete, in the same transaction (or at the next
             start, after a kill)
    history  polled values, one row per drive and history step (data: JSON of the values);
             rows older than `history_max_age_s` go at the hourly expiry; read by
             `gateway.store.history_queries`
    config_versions  each configuration applied from the console: its text (secrets sealed by
             the editor, `gateway.console.sealing`), who, when; the newest
             `MAX_CONFIG_VERSIONS` kept
    outage   running values polled while a connection to the broker was away, until it delivered
             them (`gateway.store.outage_rows`: bounded by its own size and age, and trimmed
             after the history when the store's bound is reached)
    counters a number per key that counts on across restarts (`gateway.store.counters`: the
             Sparkplug edge node's bdSeq), committed before the caller uses it

Bounds, checked after every write: the store's files (with the write-ahead log) stay within
`max_bytes` and within what the disk has, leaving a reserve free (`gateway.store.space`). Past
the bound the oldest history goes first (a chart's past is worth less than the plant's record),
then the oldest events (then, with no event left, the oldest faults); rows older
than `max_age_s` go at the hourly expiry. Events that go before the broker had them are counted
as dropped; the caller logs them. Freed pages are given back to the file system (incremental
vacuum), and the write-ahead log is checkpointed within an eighth of the bound (truncated after
each write while the disk is the bound), so the files themselves stay within it; a quarter of
it is left for a write's log. With less than
half the reserve free, nothing is written (`DiskFull`): the events wait in the caller's memory.

`synchronous=FULL`: a committed event survives a power cut, not only a killed process.
"""

from __future__ import annotations

import json
import os
import sqlite3
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

from gateway.errors import DiskFull, StoreError
from gateway.store import schema
from gateway.store.outage_rows import Gap, OutageRows, Sample
from gateway.store.owner import StoreLock
from gateway.store.records import (
    ConfigVersion,
    EventType,
    FaultRecord,
    HistoryPoint,
    NewEvent,
    StoredEvent,
)
from gateway.store.space import Room, room

MEMORY: Final = ":memory:"
TRIM_FRACTION: Final = 16
"""Past the size bound, this fraction of the events (at least one) goes per step."""
MIN_WAL_PAGES: Final = 4
MAX_WAL_PAGES: Final = 1000
WAL_FRACTION: Final = 8
"""Between two writes, SQLite checkpoints the write-ahead log past this fraction of the budget."""
MAX_CONFIG_VERSIONS: Final = 200
"""Configuration versions kept (a few kB each): years of commissioning."""
HEADROOM_FRACTION: Final = 4
"""The database keeps this fraction of the budget free for a write's log: the new events, the
trim and the vacuum that follow them, before the checkpoint gives it back."""
CACHE_KIB: Final = 512
"""SQLite's page cache for the store's connection, in KiB: a fixed bound on the memory it takes.

SQLite's default (2,000 KiB) is allocated page by page as the file is read and written, and a
page once cached stays: the gateway's memory grew with its store until the file reached 2 MB,
for hours on a plant's box (the soak: +2.5 MB after its warm-up, in steps as the outage
buffer's rows came at the broker's restarts; measured, `sqlite3_memory_used` 1.2 -> 2.1 MB
while the file grew 1 -> 2 MB, then flat). The store's work is appending and short reads near
the end of its tables; what a chart reads further back comes from the kernel's page cache,
which the system gives back when it needs the memory."""


@dataclass(slots=True)
class Batch:
    """What the writer takes in one transaction."""

    events: Sequence[NewEvent] = ()
    delivered: frozenset[int] = frozenset()
    """Ids of `events` the broker has already (published from memory): stored as delivered."""
    tallies: Mapping[str, NewEvent] = field(default_factory=dict)
    """Tallies to keep as they are now, by key."""
    history: Sequence[HistoryPoint] = ()
    """History points (a point of a drive and step written again replaces the first)."""
    samples: Sequence[Sample] = ()
    """Running values polled while the broker was away (the outage buffer)."""


@dataclass(frozen=True, slots=True)
class Appended:
    dropped: int
    """Events removed by the size bound before the broker had them."""
    bound: int
    """What the store's files may take: max_mb, or less when the disk has less."""
    gaps: list[Gap] = field(default_factory=list)
    """Outage samples removed by a bound before their connection delivered them."""


class EventDatabase:
    def __init__(
        self,
        path: str,
        max_bytes: int,
        max_age_s: float,
        forwarding: bool,
        history_max_age_s: float = 7 * 86400.0,
        shared_path: str | None = None,
        outage: OutageRows | None = None,
    ) -> None:
        self.path = path
        self.outage = outage or OutageRows(0, 0.0)
        """The outage buffer's rows and their bounds."""
        self.shared_path = shared_path
        """The default store before it was one per gateway_id (`_choose_file`); None when
        storage.path is given."""
        self.note: str | None = None
        """Which file `open` chose and why, when the shared one was considered."""
        self._lock: StoreLock | None = None
        self.max_bytes = max_bytes
        self.max_age_s = max_age_s
        self.history_max_age_s = history_max_age_s
        self.forwarding = forwarding
        """False without MQTT: events are kept for their history, nobody waits for them."""
        self._db: sqlite3.Connection | None = None
        self._page_size = 4096
        self._wal_limit_set: int | None = None
        """The write-ahead log's limit last given to SQLite (`_checkpoint`)."""

    @property
    def persistent(self) -> bool:
        return self.path != MEMORY

    # -- opening and closing -------------------------------------------------------------------

    def open(self) -> list[int]:
        """Take the file (`gateway.store.owner`), open or create it and bring its schema up to
        date; the migrations that ran. `StoreInUse` when another process holds it,
        `StoreRefused` (the file untouched) when a newer release wrote it."""
        lock = None
        try:
            if self.persistent:
                self._choose_file()
                Path(self.path).parent.mkdir(parents=True, exist_ok=True)
                lock = StoreLock(self.path)
                lock.acquire()
            db = sqlite3.connect(self.path, isolation_level=None)
        except (OSError, sqlite3.Error) as exc:
            if lock is not None:
                lock.release()
            raise StoreError(f"{self.path}: {exc}") from exc
        try:
            migrated = self._set_up(db)
        except BaseException as exc:
            db.close()
            if lock is not None:
                lock.release()
            if isinstance(exc, sqlite3.Error):
                raise StoreError(f"{self.path}: {exc}") from exc
            raise
        self._db = db
        self._lock = lock
        return migrated

    def _choose_file(self) -> None:
        """An install from before the default store was one per `gateway_id` goes on with the
        shared file it has, while this gateway has no file of its own and no other gateway
        holds the shared one (the first of two gateways started keeps it, the other starts its
        own). `note` says which, for the log."""
        shared = self.shared_path
        if shared is None or shared == self.path:
            return
        if Path(self.path).exists() or not Path(shared).exists():
            return
        if StoreLock(shared).held_elsewhere():
            self.note = (
                f"store: {shared} (the default store before it was one per gateway_id) is held "
                f"by another gateway; this one starts its own, {self.path}"
            )
            return
        self.note = (
            f"store: keeping {shared}, the default store before it was one per gateway_id; "
            f"this gateway's own default is {self.path} (to move: stop the gateway, rename "
            "the file, or set storage.path)"
        )
        self.path = shared

    def _set_up(self, db: sqlite3.Connection) -> list[int]:
        # Before anything that writes (the WAL switch is a write to the file's header): a newer
        # release's file is left exactly as it is.
        schema.refuse_newer(db, self.path)
        if schema.version(db) == 0:
            # Only before the first table: lets deletes give pages back to the file system.
            db.execute("PRAGMA auto_vacuum = INCREMENTAL")
        if self.persistent:
            mode = db.execute("PRAGMA journal_mode = WAL").fetchone()[0]
            if str(mode).lower() != "wal":
                raise sqlite3.OperationalError(f"WAL mode refused (journal mode {mode})")
        db.execute("PRAGMA synchronous = FULL")
        db.execute(f"PRAGMA cache_size = -{CACHE_KIB}")
        self._wal_limit_set = None  # a new connection: SQLite's defaults
        self._page_size = _count(db, "PRAGMA page_size")
        migrated = schema.migrate(db, self.path)
        self.outage.count(db)
        # A write that changes nothing: a file this user may read but not write (restored as
        # root, a read-only mount) is found now, not at the first event.
        db.execute(f"PRAGMA user_version = {schema.version(db)}")
        return migrated

    def close(self) -> None:
        if self._db is not None:
            self._db.close()
            self._db = None
        if self._lock is not None:
            self._lock.release()  # after the close: nobody else opens it while we write
            self._lock = None

    @property
    def db(self) -> sqlite3.Connection:
        if self._db is None:
            raise StoreError(f"{self.path}: not open")
        return self._db

    def next_id(self) -> int:
        """The id the next event gets: past every id this file ever gave (trimmed ones too)."""
        sequence = self.db.execute("SELECT seq FROM sqlite_sequence WHERE name = 'events'")
        row = sequence.fetchone()
        newest = _count(self.db, "SELECT coalesce(max(id), 0) FROM events")
        return max(newest, row[0] if row else 0) + 1

    def settle_tallies(self) -> int:
        """Tallies left by a run that was killed become events (their ids from the file);
        how many."""
        db = self.db
        delivered = 0 if self.forwarding else 1
        with _transaction(db):
            cursor = db.execute(
                "INSERT INTO events (type, time, drive, data, delivered) "
                "SELECT type, time, drive, data, ? FROM tallies ORDER BY time, key",
                (delivered,),
            )
            db.execute("DELETE FROM tallies")
        return max(0, cursor.rowcount)

    # -- writing -------------------------------------------------------------------------------

    def append(self, batch: Batch) -> Appended:
        """Store `batch` in one transaction (events with their faults, tallies); then hold the
        size bound. Raises `DiskFull` (nothing written) when the disk has less than the reserve."""
        space = self.room()
        if space.full:
            raise DiskFull(space.why_full(self.path))
        db = self.db
        undelivered = 0 if self.forwarding else 1
        with _transaction(db):
            for key, tally in batch.tallies.items():
                db.execute(
                    "INSERT OR REPLACE INTO tallies (key, type, time, drive, data) "
                    "VALUES (?, ?, ?, ?, ?)",
                    (key, tally.type, tally.time, tally.drive, _dump(tally.data)),
                )
            for event in batch.events:
                delivered = 1 if event.id in batch.delivered else undelivered
                db.execute(
                    "INSERT INTO events (id, type, time, drive, data, delivered) "
                    "VALUES (?, ?, ?, ?, ?, ?)",
                    (event.id, event.type, event.time, event.drive, _dump(event.data), delivered),
                )
                if event.settles is not None:
                    db.execute("DELETE FROM tallies WHERE key = ?", (event.settles,))
                self._fault_history(event)
            db.executemany(
                # A step a restart cut in two: the new run's values over the first's, a value
                # the new run hadn't polled yet kept from the first (not lost with a replace).
                "INSERT INTO history (drive, time, data) VALUES (?, ?, ?) "
                "ON CONFLICT (drive, time) DO UPDATE SET data = json_patch(data, excluded.data)",
                ((p.drive, p.time, _dump(p.values)) for p in batch.history),
            )
            self.outage.insert(db, batch.samples)
            gaps = self.outage.hold(db, time.time())
        bound = space.budget - space.budget // HEADROOM_FRACTION
        dropped = self._hold_size(bound, gaps)
        self._checkpoint(space)
        return Appended(dropped, space.budget, gaps)

    def room(self) -> Room:
        if not self.persistent:
            return Room(0, self.max_bytes, 0, self.max_bytes)
        return room(self.path, self.max_bytes)

    def give_back(self) -> None:
        """The disk is full: give the write-ahead log's space back (as far as it goes)."""
        if self.persistent:
            self.db.execute("PRAGMA wal_checkpoint(TRUNCATE)").fetchall()

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
            db.execute("DELETE FROM history WHERE time < ?", (now - self.history_max_age_s,))
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

    def _wal_limit(self, space: Room) -> int:
        pages = max(
            MIN_WAL_PAGES, min(MAX_WAL_PAGES, space.budget // WAL_FRACTION // self._page_size)
        )
        return pages * self._page_size

    def _checkpoint(self, space: Room) -> None:
        """SQLite's own checkpoint keeps the write-ahead log within its share of the budget.
        After a write that took the log past it, or while the disk is what bounds the store,
        the log is copied into the file and truncated at once, its space given back. (Not
        after every write: on an SD card each checkpoint is two more syncs.)"""
        if not self.persistent:
            return
        limit = self._wal_limit(space)
        if limit != self._wal_limit_set:
            # Only when it changes: each PRAGMA text is a statement of its own in the
            # connection's statement cache, and while the disk bounds the store the limit
            # changes with every write (up to 128 compiled statements held, and a compile each).
            self.db.execute(f"PRAGMA wal_autocheckpoint = {limit // self._page_size}")
            self.db.execute(f"PRAGMA journal_size_limit = {limit}")
            self._wal_limit_set = limit
        try:
            wal = os.stat(self.path + "-wal").st_size
        except FileNotFoundError:
            return
        if wal > limit or (wal and space.budget < space.max_bytes):
            self.db.execute("PRAGMA wal_checkpoint(TRUNCATE)").fetchall()

    def _hold_size(self, bound: int, gaps: list[Gap]) -> int:
        """Trim the oldest rows until the file is within `bound`; undelivered dropped (outage
        samples' to `gaps`)."""
        db = self.db
        dropped = 0
        while self.file_bytes() > bound:
            free = _count(db, "PRAGMA freelist_count")
            if free:
                # Pages freed by the last trim (or an expiry) go back to the file system first.
                db.execute("PRAGMA incremental_vacuum").fetchall()  # one page per step
                if _count(db, "PRAGMA freelist_count") < free:
                    continue
            first, last = db.execute("SELECT min(id), max(id) FROM history").fetchone()
            oldest, newest = db.execute("SELECT min(id), max(id) FROM events").fetchone()
            with _transaction(db):
                if first is not None:
                    below = first + max(1, (last - first + 1) // TRIM_FRACTION)
                    db.execute("DELETE FROM history WHERE id < ?", (below,))
                elif (trimmed := self.outage.trim_oldest(db)) is not None:
                    gaps += trimmed
                elif oldest is not None:
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

    def recent(
        self,
        limit: int,
        drive: str | None,
        types: Sequence[str] = (),
        since: float | None = None,
        until: float | None = None,
    ) -> list[StoredEvent]:
        """The newest `limit` events (of `drive`, of one of `types`, at `since` or later and
        before `until`), newest first."""
        where: list[str] = []
        args: list[object] = []
        if drive is not None:
            where.append("drive = ?")
            args.append(drive)
        if types:
            where.append(f"type IN ({', '.join('?' for _ in types)})")
            args.extend(types)
        if since is not None:
            where.append("time >= ?")
            args.append(since)
        if until is not None:
            where.append("time < ?")
            args.append(until)
        condition = f"WHERE {' AND '.join(where)} " if where else ""
        sql = f"SELECT id, type, time, data FROM events {condition}ORDER BY id DESC LIMIT ?"
        return [_event(row) for row in self.db.execute(sql, (*args, limit)).fetchall()]

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

    def open_faults(self) -> dict[str, int]:
        """Drive → the code of its fault raised and not cleared (as the last run saw it)."""
        rows = self.db.execute(
            "SELECT drive, code FROM faults WHERE cleared IS NULL ORDER BY id"
        ).fetchall()
        return {drive: code for drive, code in rows}  # the newest per drive wins

    def add_config_version(self, at: float, user: str, text: str, note: str) -> int:
        """Keep a configuration's text; its version number. The oldest past
        `MAX_CONFIG_VERSIONS` go."""
        db = self.db
        with _transaction(db):
            cursor = db.execute(
                "INSERT INTO config_versions (time, user, text, note) VALUES (?, ?, ?, ?)",
                (at, user, text, note),
            )
            number = int(cursor.lastrowid or 0)
            db.execute("DELETE FROM config_versions WHERE id <= ?", (number - MAX_CONFIG_VERSIONS,))
        return number

    def remove_config_version(self, number: int) -> None:
        """A version kept for an apply that did not happen (the reload refused it)."""
        with _transaction(self.db):
            self.db.execute("DELETE FROM config_versions WHERE id = ?", (number,))

    def config_versions(self) -> list[ConfigVersion]:
        """Every version kept, newest first."""
        rows = self.db.execute(
            "SELECT id, time, user, text, note FROM config_versions ORDER BY id DESC"
        ).fetchall()
        return [ConfigVersion(*row) for row in rows]

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
        if kind is None:
            self.db.execute("COMMIT")
        elif self.db.in_transaction:  # SQLite rolls back by itself on some errors (a full disk)
            self.db.execute("ROLLBACK")


def _count(db: sqlite3.Connection, sql: str, *args: Any) -> int:
    value: int = db.execute(sql, args).fetchone()[0]
    return value


def _event(row: tuple[Any, ...]) -> StoredEvent:
    return StoredEvent(row[0], row[1], row[2], json.loads(row[3]))


def _dump(value: object) -> str:
    return json.dumps(value, separators=(",", ":"), sort_keys=False)
