"""The history of polled values: one point per drive and step, kept in the store for charts.

The poller's state of a drive (`Telemetry`) is averaged over each history step
(`storage.history_step_s`, a minute by default): a number is the mean of the polls in the step,
a text value (the state) as it was last, a true/false the share of polls it was true. When the
step is over, its point goes to the store's writer with the next write (one transaction, on the
store's thread, like the events); a point of a drive and step written again (the step a restart
cut in two) is merged with the first: the new run's values over the first's, a value only the
first run had polled kept. What the disk can't take waits in memory, at most
`MAX_WAITING_POINTS`, the oldest dropped first; nothing else changes when the disk is full.

Disk use: one row per drive and step, about 30 bytes plus 25 per value (a GD350 polled for
its running values has about 15): some 400 bytes, so a drive kept 7 days at one point a minute
takes 4 MB. The history shares `storage.max_mb` with the events; past it the oldest history
goes first, and rows older than `storage.history_days` go at the hourly expiry.

`values` is the one place that says which of a drive's polled values are history (and chart)
values: the console's live charts take the same.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Final

from gateway.profile.telemetry import Telemetry
from gateway.store.records import HistoryPoint

MAX_WAITING_POINTS: Final = 10_000
"""History points waiting for the disk (a full or failing one): an hour of 160 drives."""
NOT_HISTORY: Final = frozenset({"last_seen", "fault_name", "fault_description"})
"""Polled values that are not the drive's own measurements or state (shown elsewhere)."""
MAX_TEXT: Final = 64

Value = float | str


def values(telemetry: Mapping[str, object]) -> dict[str, Value]:
    """The values of a drive's state worth a history: numbers (true/false as 1/0) and short
    texts (the state), by key."""
    found: dict[str, Value] = {}
    for key, value in telemetry.items():
        if key in NOT_HISTORY:
            continue
        if isinstance(value, bool):
            found[key] = 1.0 if value else 0.0
        elif isinstance(value, int | float):
            if math.isfinite(value):
                found[key] = float(value)
        elif isinstance(value, str) and len(value) <= MAX_TEXT:
            found[key] = value
    return found


@dataclass(slots=True)
class _Step:
    start: float
    sums: dict[str, float] = field(default_factory=dict)
    counts: dict[str, int] = field(default_factory=dict)
    texts: dict[str, str] = field(default_factory=dict)

    def add(self, found: Mapping[str, Value]) -> None:
        for key, value in found.items():
            if isinstance(value, str):
                self.texts[key] = value
            else:
                self.sums[key] = self.sums.get(key, 0.0) + value
                self.counts[key] = self.counts.get(key, 0) + 1

    def point(self, drive: str) -> HistoryPoint:
        means: dict[str, Value] = {k: round(s / self.counts[k], 6) for k, s in self.sums.items()}
        return HistoryPoint(drive, self.start, {**means, **self.texts})


class HistoryRecorder:
    """A poll listener (`gateway.poller.PollListener`): averages each drive's polls over the
    step and hands each finished step's point to `keep`."""

    def __init__(
        self,
        keep: Callable[[HistoryPoint], None],
        step_s: float,
        clock: Callable[[], float] = time.time,
    ) -> None:
        self.keep = keep
        self.step_s = step_s
        self.enabled = True
        self._clock = clock
        self._steps: dict[str, _Step] = {}

    def state_updated(self, drive: str, telemetry: Telemetry) -> None:
        if not self.enabled:
            return
        now = self._clock()
        start = now - now % self.step_s
        step = self._steps.get(drive)
        if step is None or step.start != start:
            if step is not None and step.counts.keys() | step.texts.keys():
                self.keep(step.point(drive))
            step = self._steps[drive] = _Step(start)
        step.add(values(telemetry))

    def availability_changed(self, drive: str, online: bool) -> None:
        pass  # an offline drive has no values: its history has a gap there

    def drive_event(self, event: object) -> None:
        pass

    def finish(self) -> None:
        """The gateway stops: each step begun is kept as far as it went (a restart within the
        step merges what the new run sees over it)."""
        for drive, step in self._steps.items():
            if step.counts or step.texts:
                self.keep(step.point(drive))
        self._steps.clear()


@dataclass(frozen=True, slots=True)
class Series:
    """Values of one drive over a window, as columns: what a chart and a CSV file take."""

    keys: tuple[str, ...]
    times: list[float]
    columns: list[list[Value | None]]
    step_s: float
    """The time one point stands for."""


def span_for(window_s: float, step_s: float, max_points: int) -> float:
    """The span (a whole number of steps) whose points, aligned to the clock, cover a window
    of `window_s` in at most `max_points` points: what the store reduces a window to."""
    steps = math.ceil(window_s / step_s / max(1, max_points - 1)) if max_points > 1 else 0
    return step_s * max(1, steps) if max_points > 1 else step_s * math.ceil(window_s / step_s)


def series(
    points: Sequence[tuple[float, Mapping[str, Value]]],
    keys: Sequence[str],
    step_s: float,
    max_points: int,
) -> Series:
    """`points` (oldest first, each `step_s` apart at least) for `keys`, at most `max_points`:
    when there are more, the points within each span of a few steps (spans aligned to the
    clock, so the same window gives the same points) are merged: numbers averaged, texts the
    last."""
    if len(points) <= max(1, max_points):
        # Nothing to merge (the store reduced a long window already): a pass per value, not a
        # merge per point; the console runs this on the event loop for up to a chart's points.
        columns = [_column(points, key) for key in keys]
        return Series(tuple(keys), [at for at, _ in points], columns, step_s)
    factor = max(1, math.ceil(len(points) / max(1, max_points)))
    while True:
        shown = _merged(points, keys, step_s * factor if factor > 1 else 0.0)
        if len(shown.times) <= max(1, max_points):
            return Series(shown.keys, shown.times, shown.columns, step_s * factor)
        factor += max(1, factor // 4)  # a gap split a span: wider ones


def _column(points: Sequence[tuple[float, Mapping[str, Value]]], key: str) -> list[Value | None]:
    """`key`'s value at each point (None where it has none), numbers as a merge gives them."""
    column: list[Value | None] = []
    for _, found in points:
        value = found.get(key)
        column.append(value if value is None or isinstance(value, str) else round(value, 6))
    return column


def _merged(
    points: Sequence[tuple[float, Mapping[str, Value]]], keys: Sequence[str], span_s: float
) -> Series:
    times: list[float] = []
    columns: list[list[Value | None]] = [[] for _ in keys]
    bucket: list[Mapping[str, Value]] = []
    bucket_start: float | None = None
    for at, found in points:
        start = at - at % span_s if span_s else at
        if bucket_start is not None and start != bucket_start:
            _merge(bucket_start, bucket, keys, times, columns)
            bucket = []
        bucket_start = start
        bucket.append(found)
    if bucket_start is not None:
        _merge(bucket_start, bucket, keys, times, columns)
    return Series(tuple(keys), times, columns, span_s)


def _merge(
    at: float,
    bucket: Sequence[Mapping[str, Value]],
    keys: Sequence[str],
    times: list[float],
    columns: list[list[Value | None]],
) -> None:
    times.append(at)
    for key, column in zip(keys, columns, strict=True):
        present = [found[key] for found in bucket if key in found]
        numbers = [v for v in present if not isinstance(v, str)]
        if numbers:
            column.append(round(sum(numbers) / len(numbers), 6))
        elif present:
            column.append(present[-1])
        else:
            column.append(None)
