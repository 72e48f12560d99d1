"""A device's reads, planned from its points: as few requests as the device allows.

Points of one table and one poll interval, in address order, share a request while the request
stays within the device's maximum (`max_registers`, or `max_bits` on coils and discrete inputs)
and the registers between two points number no more than `max_gap` (read and thrown away: one
longer request costs less line time than two). A point is never cut in two: its registers
arrive in one reply, so a 32-bit value can't be torn between two readings.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from itertools import groupby

from gateway.profile.point_types import Table, TypedPoint
from gateway.profile.protocol import PollGroup


@dataclass(frozen=True, slots=True)
class Limits:
    max_registers: int
    max_bits: int
    max_gap: int
    interval_s: float

    def most(self, table: Table) -> int:
        return self.max_bits if table.bits else self.max_registers


def plan_reads(points: Iterable[TypedPoint], limits: Limits) -> tuple[PollGroup, ...]:
    """The poll groups that read every point, each one request on the wire."""

    def rhythm(point: TypedPoint) -> tuple[str, float]:
        return point.table.value, point.interval_s or limits.interval_s

    groups: list[PollGroup] = []
    for (_, interval_s), together in groupby(sorted(points, key=rhythm), key=rhythm):
        ordered = sorted(together, key=lambda p: p.address)
        for start, end, table in _spans(ordered, limits):
            name = f"{table.value}_{start}"
            groups.append(PollGroup(name, start, end - start, interval_s, table))
    return tuple(groups)


def _spans(points: list[TypedPoint], limits: Limits) -> list[tuple[int, int, Table]]:
    spans: list[tuple[int, int, Table]] = []
    for point in points:
        most = limits.most(point.table)
        if spans:
            start, end, table = spans[-1]
            gap = point.address - end
            if gap <= limits.max_gap and max(end, point.end) - start <= most:
                spans[-1] = (start, max(end, point.end), table)
                continue
        spans.append((point.address, point.end, point.table))
    return spans
