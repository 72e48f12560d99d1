"""The store's memory is bounded, not its file's size: SQLite's page cache for the store stays
within `CACHE_KIB` however large the file grows (the soak's growth after its warm-up, issue 45:
SQLite's default cache took a page more of memory for every page the file grew, to 2 MB)."""

from __future__ import annotations

import ctypes
import ctypes.util
import sqlite3
import time
from pathlib import Path

import pytest

from gateway.config import StorageConfig
from gateway.store.database import CACHE_KIB
from tests.support.store import running_store

VALUES = {f"value_{n:02d}": 1000.0 + n for n in range(14)}
"""About what a GD350's running values take: 14 numbers."""
OUTAGE_MB = 3.0
"""What a broker's outage leaves in the file: six times the page cache."""


def sqlite_memory_used() -> int | None:
    """Bytes SQLite holds in this process, as SQLite counts them (its page caches, schemas,
    statements); None where the library `sqlite3` uses can't be asked (linked in statically)."""
    name = ctypes.util.find_library("sqlite3")
    if name is None:
        return None
    library = ctypes.CDLL(name)
    library.sqlite3_libversion.restype = ctypes.c_char_p
    if library.sqlite3_libversion().decode() != sqlite3.sqlite_version:
        return None
    library.sqlite3_memory_used.restype = ctypes.c_int64
    used = int(library.sqlite3_memory_used())
    return used if used > 0 else None  # 0 with a store open: another copy of the library


async def test_a_store_that_grows_keeps_its_memory_within_the_page_cache_bound(
    tmp_path: Path,
) -> None:
    path = tmp_path / "events.db"
    config = StorageConfig(path=str(path), max_mb=16, outage_buffer_mb=8)
    start = time.time() - 3600
    async with running_store(config) as store:
        baseline = sqlite_memory_used()
        if baseline is None:
            pytest.skip("SQLite's memory can't be read here (a static copy of the library)")
        # A broker away for a long while: polled values kept for it, written to the file.
        n = 0
        while path.stat().st_size < OUTAGE_MB * 1024 * 1024:
            for _ in range(1000):
                store.keep_sample("json", "pump1", {**VALUES, "sample": n}, start + n / 10)
                n += 1
            await store.flush()
            # Read back as the connection back would: the whole file passes through the cache.
            assert await store.outage_samples("json", 0, 1)
        used = sqlite_memory_used()
    assert used is not None
    assert used - baseline < CACHE_KIB * 1024, (
        f"SQLite's memory grew {(used - baseline) // 1024} kB while the file grew to "
        f"{path.stat().st_size // 1024} kB"
    )
