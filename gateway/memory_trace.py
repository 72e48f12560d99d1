"""Where the gateway's memory goes, on request: tracemalloc snapshots a soak can compare.

    INVT_GATEWAY_TRACEMALLOC=/some/folder invt-gateway run --config FILE
    kill -USR2 <pid>        → /some/folder/snapshot-<pid>-<n>.tracemalloc

Off unless the variable is set (tracing every allocation costs the loop about a third of its
speed and memory of its own). Two snapshots compared (`tracemalloc.Snapshot.load`,
`compare_to`) name the lines whose allocations grew between them: `invt-gateway stress --soak
HOURS --tracemalloc` takes them after its warm-up and at every sample, and prints the lines
that grew most.

The snapshot is written from a plain signal handler, on the loop's thread between two of its
callbacks: a second or so during which the gateway answers nothing, which a diagnosis can
afford and a service never pays unless asked.
"""

from __future__ import annotations

import itertools
import os
import signal
import tracemalloc
from pathlib import Path
from types import FrameType
from typing import Final

ENVIRONMENT: Final = "INVT_GATEWAY_TRACEMALLOC"
SIGNAL: Final = signal.SIGUSR2
FRAMES: Final = 8
"""Frames kept per allocation: enough to see who called the helper that allocated."""
SUFFIX: Final = ".tracemalloc"


def trace_from_environment() -> Path | None:
    """Start tracing and answer `SIGNAL` with a snapshot when `ENVIRONMENT` names a folder;
    the folder, or None when it is not set."""
    folder = os.environ.get(ENVIRONMENT)
    if not folder:
        return None
    where = Path(folder)
    where.mkdir(parents=True, exist_ok=True)
    tracemalloc.start(FRAMES)
    numbers = itertools.count(1)

    def write_snapshot(signum: int, frame: FrameType | None) -> None:
        path = snapshot_path(where, os.getpid(), next(numbers))
        partial = path.with_suffix(".partial")
        tracemalloc.take_snapshot().dump(str(partial))
        partial.rename(path)  # whole or absent: the soak reads it as soon as it is there

    signal.signal(SIGNAL, write_snapshot)
    return where


def snapshot_path(folder: Path, pid: int, number: int) -> Path:
    return folder / f"snapshot-{pid}-{number:04d}{SUFFIX}"
