"""A small file system of its own for a store to fill: a tmpfs of a given size, mounted for the
test and unmounted after it. Mounting needs root (the development container runs the tests as
root); elsewhere these tests are skipped, and say why."""

from __future__ import annotations

import contextlib
import errno
import os
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest

CHUNK = 16 * 1024


@contextlib.contextmanager
def small_disk(mount_point: Path, size: str = "2m") -> Iterator[Path]:
    """`mount_point`, a tmpfs of `size` (mount's `size=`), for as long as the block lasts."""
    if os.geteuid() != 0:
        pytest.skip("mounting a small file system needs root")
    mount_point.mkdir(parents=True, exist_ok=True)
    subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(mount_point)], check=True
    )
    try:
        yield mount_point
    finally:
        subprocess.run(["umount", "--lazy", str(mount_point)], check=True)


def fill(path: Path) -> int:
    """Write `path` until the disk is full, as a runaway log would; how many bytes it took."""
    written = 0
    chunk = CHUNK
    descriptor = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC)
    try:
        while chunk:
            try:
                written += os.write(descriptor, b"\0" * chunk)
            except OSError as exc:
                if exc.errno != errno.ENOSPC:
                    raise
                chunk //= 2
    finally:
        os.close(descriptor)
    return written


def free_bytes(path: Path) -> int:
    stat = os.statvfs(path)
    return stat.f_bavail * stat.f_frsize


@contextlib.contextmanager
def read_only(path: Path) -> Iterator[Path]:
    """`path` read-only for every process, root too, for as long as the block lasts: a mount
    point remounted read-only (a disk that went read-only), a file bound read-only over itself
    (a file the service's user may read but not write, as one restored by root)."""
    if path.is_mount():
        subprocess.run(["mount", "-o", "remount,ro", str(path)], check=True)
        try:
            yield path
        finally:
            subprocess.run(["mount", "-o", "remount,rw", str(path)], check=True)
        return
    subprocess.run(["mount", "--bind", "-o", "ro", str(path), str(path)], check=True)
    try:
        yield path
    finally:
        subprocess.run(["umount", str(path)], check=True)
