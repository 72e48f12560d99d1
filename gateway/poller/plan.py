"""What to read from a drive and how often: poll groups cut into requests the drive accepts.

A group comes from the YAML (`drives[].poll`) or, when the drive has none, from its profile
(state words and fault code every 0.5 s, the running values 3000H-300BH every 2 s on INVT). INVT
drives answer at most 16 words per 03H request, so a group is read as several blocks of at most
the profile's `max_words`, each one request on the bus. A device file's groups are planned by
its profile (`gateway.profile.read_plan`), each within its limit already, of any Modbus table.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

from gateway.modbus.functions import (
    READ_COILS,
    READ_DISCRETE_INPUTS,
    READ_HOLDING_REGISTERS,
    READ_INPUT_REGISTERS,
)
from gateway.profile.point_types import Table
from gateway.settings import DriveSettings

READ_FUNCTION: Final = {
    Table.HOLDING: READ_HOLDING_REGISTERS,
    Table.INPUT: READ_INPUT_REGISTERS,
    Table.COIL: READ_COILS,
    Table.DISCRETE_INPUT: READ_DISCRETE_INPUTS,
}


@dataclass(frozen=True, slots=True)
class PollBlock:
    """One read request: `count` words (bits of a coil or discrete input) of `table` from
    `start`."""

    start: int
    count: int
    table: Table = Table.HOLDING

    @property
    def function(self) -> int:
        return READ_FUNCTION[self.table]


@dataclass(frozen=True, slots=True)
class PollSchedule:
    group: str
    interval_s: float
    blocks: tuple[PollBlock, ...]


def poll_schedules(drive: DriveSettings) -> tuple[PollSchedule, ...]:
    max_words = drive.profile.max_words
    return tuple(
        PollSchedule(g.name, g.interval_s, blocks(g.start, g.count, max_words, g.table))
        for g in drive.poll_groups
    )


def blocks(
    start: int, count: int, max_words: int, table: Table = Table.HOLDING
) -> tuple[PollBlock, ...]:
    most = max(max_words, count) if table.bits else max_words  # bits: the group is the limit
    return tuple(
        PollBlock(start + offset, min(most, count - offset), table)
        for offset in range(0, count, most)
    )
