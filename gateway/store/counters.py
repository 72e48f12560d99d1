"""Numbers that count on across restarts (the Sparkplug edge node's bdSeq), in the store's
`counters` table. On the store's thread, like every use of the file (`gateway.store.reads`
calls it)."""

from __future__ import annotations

import sqlite3


def count_on(db: sqlite3.Connection, key: str, modulo: int, after: int | None = None) -> int:
    """The counter `key` one further (0 the first time, `modulo` wraps to 0), committed before
    it is returned: a power cut after its use never hands it out again. `after`: one further
    than that instead of the kept value (a redundant box going on from the other box's count)."""
    db.execute("BEGIN IMMEDIATE")
    try:
        row = db.execute("SELECT value FROM counters WHERE key = ?", (key,)).fetchone()
        last = after if after is not None else None if row is None else int(row[0])
        value = 0 if last is None else (last + 1) % modulo
        db.execute(
            "INSERT INTO counters (key, value) VALUES (?, ?) "
            "ON CONFLICT (key) DO UPDATE SET value = excluded.value",
            (key, value),
        )
    except BaseException:
        if db.in_transaction:
            db.execute("ROLLBACK")
        raise
    db.execute("COMMIT")
    return value
