"""One store, one owner: a gateway holds its store's file for as long as it has it open.

SQLite lets two processes write one file, and two gateways would: each numbers its events from
the file's newest id at start, so the second one's writes collide with the first's (`UNIQUE
constraint failed: events.id`) and events are lost. So the store takes an advisory lock
(`flock`, exclusive, not waiting) on a file beside the database, `<storage.path>.lock`, before it
opens the database, and holds it until it closes it (the process's life; the kernel lets go of
it when the process dies, even by SIGKILL, so a crash leaves nothing to clean up). The holder
writes its pid into the lock file: a second gateway is refused with one line naming the file and
that pid, and the first is not touched.

`flock` rather than `fcntl` locks: those are per process (a second open in the same process
would pass, and closing any descriptor of the file drops them), `flock`'s are per open file.
The lock file is never removed: removing it would let a third process lock a new file of the
same name while the first still holds the old one.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
from pathlib import Path
from typing import Final

from gateway.errors import StoreInUse

LOCK_SUFFIX: Final = ".lock"


class StoreLock:
    """The exclusive hold on one store file, by this process."""

    def __init__(self, path: str) -> None:
        self.path = path
        self.lock_path = path + LOCK_SUFFIX
        self._fd: int | None = None

    def acquire(self) -> None:
        """Take the lock, or raise `StoreInUse` naming the holder. `OSError` when the lock file
        can't be made (a directory this user can't write: the database couldn't be either)."""
        fd = os.open(self.lock_path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _holder(fd)
            os.close(fd)
            raise StoreInUse(
                f"storage.path {self.path}: in use by another gateway ({holder}, lock "
                f"{self.lock_path}); give each gateway its own storage.path"
            ) from None
        except BaseException:
            os.close(fd)
            raise
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        self._fd = fd

    def held_elsewhere(self) -> bool:
        """Whether another process holds this file now (looked at without keeping it)."""
        if not Path(self.lock_path).exists():
            return False
        try:
            self.acquire()
        except StoreInUse:
            return True
        except OSError:
            return False
        self.release()
        return False

    def release(self) -> None:
        if self._fd is not None:
            os.close(self._fd)  # closing the only descriptor lets go of the lock
            self._fd = None


def _holder(fd: int) -> str:
    """The holder as "pid N", from the lock file; the holder may not have written it yet (it
    took the lock a moment ago)."""
    with contextlib.suppress(OSError, ValueError):
        pid = int(os.pread(fd, 32, 0).decode("ascii").strip())
        return f"pid {pid}"
    return "pid not known yet"
