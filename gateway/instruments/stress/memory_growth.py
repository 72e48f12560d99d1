"""Which lines of the gateway hold more memory at the end of a soak than after its warm-up:
two tracemalloc snapshots (`gateway.memory_trace`) compared."""

from __future__ import annotations

import tracemalloc
from dataclasses import dataclass
from pathlib import Path
from typing import Final

TOP: Final = 12
IGNORED: Final = (
    tracemalloc.Filter(False, tracemalloc.__file__),
    tracemalloc.Filter(False, "<frozen importlib._bootstrap>"),
    tracemalloc.Filter(False, "<frozen importlib._bootstrap_external>"),
    tracemalloc.Filter(False, "<unknown>"),
)
OURS: Final = "/gateway/"


@dataclass(frozen=True, slots=True)
class Growth:
    where: str
    """The line that allocated ("gateway/console/auth.py:125", or a library's)."""
    grown_kb: float
    blocks: int
    """How many more memory blocks it holds."""
    caller: str
    """The nearest line of the gateway's own on the way there (the allocating one if ours)."""


def growth_between(first: Path, last: Path, top: int = TOP) -> list[Growth]:
    """The `top` lines whose allocations grew most from `first` to `last`."""
    old = tracemalloc.Snapshot.load(str(first)).filter_traces(IGNORED)
    new = tracemalloc.Snapshot.load(str(last)).filter_traces(IGNORED)
    callers: dict[str, tuple[int, str]] = {}
    for stat in new.compare_to(old, "traceback"):
        frames = list(reversed(stat.traceback))  # the allocating frame first
        line = _frame(frames[0])
        ours = next((f for f in frames if OURS in f.filename), frames[0])
        if stat.size_diff > callers.get(line, (0, ""))[0]:
            callers[line] = (stat.size_diff, _frame(ours))
    grown = [s for s in new.compare_to(old, "lineno") if s.size_diff > 0][:top]
    return [
        Growth(
            _frame(s.traceback[0]),
            s.size_diff / 1024,
            s.count_diff,
            callers.get(_frame(s.traceback[0]), (0, ""))[1],
        )
        for s in grown
    ]


def _frame(frame: tracemalloc.Frame) -> str:
    name = frame.filename
    at = name.rfind(OURS)
    short = name[at + 1 :] if at >= 0 else "/".join(Path(name).parts[-2:])
    return f"{short}:{frame.lineno}"
