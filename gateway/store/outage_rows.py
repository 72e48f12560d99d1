"""The outage buffer's rows: running values polled while a connection to the broker was away,
kept in the store's file until that connection has delivered them. Used only from the store's
own thread (`gateway.store.database`), inside its transactions.

    outage   id (in the order polled; never given twice, so a reader that goes on after the
             last id it delivered misses none: AUTOINCREMENT), route (the connection that will
             deliver it: `json`, the bridge's history messages; `sparkplug`, the edge node's
             historical DDATA), drive, time (when polled), data (JSON of the values that were
             news at that poll)

Bounds: `storage.outage_buffer_mb` of the store's `storage.max_mb` (the rows' data plus
`ROW_OVERHEAD` each), and `storage.outage_buffer_hours`; past either the oldest go first.
What goes before its connection delivered it is a `Gap` (per route and drive: from, to, how
many), for the caller to count, log and mark.
"""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Final

ROW_OVERHEAD: Final = 48
"""A row's bytes beside its data: id, route, drive, time and SQLite's own (measured: 20,000
samples of two changed values took 96 bytes of file each, and are counted as 99)."""
TRIM_FRACTION: Final = 16

Value = bool | int | float | str


@dataclass(frozen=True, slots=True)
class Sample:
    """Values of one drive at one poll, for one route."""

    route: str
    drive: str
    time: float
    values: Mapping[str, Value]


@dataclass(frozen=True, slots=True)
class KeptSample:
    id: int
    drive: str
    time: float
    values: dict[str, Value]


@dataclass(frozen=True, slots=True)
class Gap:
    """Samples of one route and drive that went before they were delivered."""

    route: str
    drive: str
    start: float
    end: float
    samples: int


class OutageRows:
    """The rows' size, kept as they come and go (summing them at every write would read the
    whole table)."""

    def __init__(self, max_bytes: int, max_age_s: float) -> None:
        self.max_bytes = max_bytes
        self.max_age_s = max_age_s
        self.bytes = 0

    def count(self, db: sqlite3.Connection) -> None:
        """At open: what the last run left."""
        row = db.execute(
            f"SELECT coalesce(sum(length(data)), 0) + count(*) * {ROW_OVERHEAD} FROM outage"
        ).fetchone()
        self.bytes = int(row[0])

    def insert(self, db: sqlite3.Connection, samples: Iterable[Sample]) -> None:
        for sample in samples:
            data = json.dumps(sample.values, separators=(",", ":"))
            db.execute(
                "INSERT INTO outage (route, drive, time, data) VALUES (?, ?, ?, ?)",
                (sample.route, sample.drive, sample.time, data),
            )
            self.bytes += len(data) + ROW_OVERHEAD

    def hold(self, db: sqlite3.Connection, now: float) -> list[Gap]:
        """The oldest rows out until within the size and age bounds: what went undelivered."""
        cutoff = now - self.max_age_s
        oldest = db.execute("SELECT time FROM outage ORDER BY id LIMIT 1").fetchone()
        # The rows go in by id as they were polled: only when the first is too old is the
        # table read for the others (not at every write).
        gaps = self._remove(db, "time < ?", cutoff) if oldest and oldest[0] < cutoff else []
        while self.bytes > self.max_bytes:
            first, last = db.execute("SELECT min(id), max(id) FROM outage").fetchone()
            if first is None:
                self.bytes = 0
                break
            below = first + max(1, (last - first + 1) // TRIM_FRACTION)
            gaps += self._remove(db, "id < ?", below)
        return gaps

    def trim_oldest(self, db: sqlite3.Connection) -> list[Gap] | None:
        """One step of the store's size bound (the file's): the oldest sixteenth out; None when
        there is nothing to trim."""
        first, last = db.execute("SELECT min(id), max(id) FROM outage").fetchone()
        if first is None:
            return None
        return self._remove(db, "id < ?", first + max(1, (last - first + 1) // TRIM_FRACTION))

    def take(self, db: sqlite3.Connection, route: str, after: int, limit: int) -> list[KeptSample]:
        rows = db.execute(
            "SELECT id, drive, time, data FROM outage WHERE route = ? AND id > ? "
            "ORDER BY id LIMIT ?",
            (route, after, limit),
        ).fetchall()
        return [KeptSample(row[0], row[1], row[2], json.loads(row[3])) for row in rows]

    def delivered(self, db: sqlite3.Connection, route: str, up_to: int) -> None:
        """Delivered: out of the file (one statement, committed by itself)."""
        self.bytes -= _bytes(db, "route = ? AND id <= ?", route, up_to)
        db.execute("DELETE FROM outage WHERE route = ? AND id <= ?", (route, up_to))

    def _remove(self, db: sqlite3.Connection, where: str, bound: float) -> list[Gap]:
        rows = db.execute(
            f"SELECT route, drive, min(time), max(time), count(*) FROM outage WHERE {where} "
            "GROUP BY route, drive",
            (bound,),
        ).fetchall()
        if rows:
            self.bytes -= _bytes(db, where, bound)
            db.execute(f"DELETE FROM outage WHERE {where}", (bound,))
        return [Gap(*row) for row in rows]


def _bytes(db: sqlite3.Connection, where: str, *args: object) -> int:
    row = db.execute(
        f"SELECT coalesce(sum(length(data)), 0) + count(*) * {ROW_OVERHEAD} FROM outage "
        f"WHERE {where}",
        args,
    ).fetchone()
    return int(row[0])
