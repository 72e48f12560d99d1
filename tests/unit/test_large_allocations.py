"""glibc keeps a thread's large freed blocks once it has raised its mmap threshold; the gateway
fixes the threshold at start (`gateway.large_allocations`). Each case runs in a process of its
own: the threshold is the whole process's."""

from __future__ import annotations

import subprocess
import sys

import pytest

from gateway.libc import process_libc

# Four logins' scrypt (gateway.passwords' cost) on four worker threads at once, as the console
# checks passwords; then the resident anonymous memory, in MiB, against before.
LOGINS = """
import hashlib, sys
from concurrent.futures import ThreadPoolExecutor
from gateway.large_allocations import give_back_large_allocations
from gateway.passwords import SCRYPT_N, SCRYPT_P, SCRYPT_R

def resident_mib():
    with open("/proc/self/status") as status:
        return next(int(l.split()[1]) for l in status if l.startswith("RssAnon")) / 1024

if sys.argv[1] == "fixed":
    assert give_back_large_allocations()
before = resident_mib()
def login(_):
    return hashlib.scrypt(b"pw", salt=b"s" * 16, n=SCRYPT_N, r=SCRYPT_R, p=SCRYPT_P,
                          maxmem=64 << 20)
with ThreadPoolExecutor(4) as threads:
    for _ in range(3):
        list(threads.map(login, range(4)))
print(resident_mib() - before)
"""


GLIBC = hasattr(process_libc(), "mallopt")


def kept_mib(how: str) -> float:
    run = subprocess.run(
        [sys.executable, "-c", LOGINS, how], capture_output=True, text=True, check=True
    )
    return float(run.stdout)


@pytest.mark.skipif(not GLIBC, reason="glibc's malloc only")
def test_logins_on_worker_threads_keep_no_memory_once_the_threshold_is_fixed() -> None:
    assert kept_mib("fixed") < 4


@pytest.mark.skipif(not GLIBC, reason="glibc's malloc only")
def test_glibc_still_keeps_a_threads_large_blocks_without_it() -> None:
    """The day this fails, glibc gives them back by itself and the workaround can go."""
    assert kept_mib("default") >= 16
