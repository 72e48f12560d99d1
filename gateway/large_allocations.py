"""Large allocations given back to the system when freed, whichever thread made them.

glibc serves an allocation of `M_MMAP_THRESHOLD` or more (128 kiB at start) with a mapping of
its own, unmapped when freed. But the first time such a mapping is freed, glibc raises the
threshold to its size (up to 32 MiB), so that the next allocations of that size come from the
thread's arena instead, and an arena gives little back. A console login checks its password with
scrypt (`gateway.passwords`: 16 MiB of working memory) on one of the event loop's worker
threads: each thread that once did kept 16 MiB resident for good (the soak: 48 -> 64 -> 80 MB
as logins landed on new threads; a script alone: 6 -> 22 MB after one scrypt, 22 thereafter).
Setting the threshold fixes it where glibc starts and turns the raising off: such a block is
mapped and unmapped each time (a login's, a large answer's), microseconds beside its work.

Elsewhere than glibc (or if the call is refused) nothing changes.
"""

from __future__ import annotations

from typing import Final

from gateway.libc import process_libc

M_MMAP_THRESHOLD: Final = -3  # glibc's malloc.h
THRESHOLD_BYTES: Final = 128 * 1024
"""glibc's own starting value, kept."""


def give_back_large_allocations() -> bool:
    """Fix glibc's mmap threshold for the process; True if it took it."""
    libc = process_libc()
    if libc is None or not hasattr(libc, "mallopt"):
        return False
    return int(libc.mallopt(M_MMAP_THRESHOLD, THRESHOLD_BYTES)) == 1
