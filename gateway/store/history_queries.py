"""The history of polled values in the store's file, as the console's charts read it: a
window's points as they are, how many there are, or one point per span reduced in SQLite (so a
window of months never comes into Python's memory whole). On the store's thread, like every
use of the file (`gateway.store.reads` calls them); the points are written with the events
(`database.EventDatabase.append`)."""

from __future__ import annotations

import json
import sqlite3


def points(
    db: sqlite3.Connection, drive: str, since: float, until: float
) -> list[tuple[float, dict[str, float | str]]]:
    """`drive`'s history points from `since` to before `until`, oldest first."""
    rows = db.execute(
        "SELECT time, data FROM history WHERE drive = ? AND time >= ? AND time < ? ORDER BY time",
        (drive, since, until),
    ).fetchall()
    return [(row[0], json.loads(row[1])) for row in rows]


def count(db: sqlite3.Connection, drive: str, since: float, until: float) -> int:
    row = db.execute(
        "SELECT count(*) FROM history WHERE drive = ? AND time >= ? AND time < ?",
        (drive, since, until),
    ).fetchone()
    return int(row[0])


def reduced(
    db: sqlite3.Connection, drive: str, since: float, until: float, span_s: float
) -> list[tuple[float, dict[str, float | str]]]:
    """`drive`'s history from `since` to before `until` as one point per `span_s` (spans
    aligned to the clock, each at its start), oldest first: a number the mean of the span's,
    a text the last. Reduced in SQLite, so that a window of months never comes into
    Python's memory whole: the answer has (window / span) x (values) rows at most."""
    rows = db.execute(
        "SELECT CAST(h.time / :span AS INTEGER) * :span AS at, j.key, "
        "avg(CASE WHEN j.type IN ('integer', 'real') THEN j.value END), "
        # The one max() makes the bare j.value the text of the span's last row (SQLite).
        "max(CASE WHEN j.type = 'text' THEN h.time END), j.value "
        "FROM history AS h, json_each(h.data) AS j "
        "WHERE h.drive = :drive AND h.time >= :since AND h.time < :until "
        "GROUP BY at, j.key ORDER BY at",
        {"span": span_s, "drive": drive, "since": since, "until": until},
    )
    points: dict[float, dict[str, float | str]] = {}
    for at, key, mean, last_text, text in rows:
        if mean is not None:
            points.setdefault(at, {})[key] = round(mean, 6)
        elif last_text is not None:
            points.setdefault(at, {})[key] = text
    return list(points.items())


def rows(db: sqlite3.Connection) -> int:
    """Every drive's points, all told."""
    row = db.execute("SELECT count(*) FROM history").fetchone()
    return int(row[0])
