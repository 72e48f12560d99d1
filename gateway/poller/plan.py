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


WORDS_WHILE_READS_WAIT: Final = 8
"""While SCADA reads wait for the line, a poll block of more words goes as pieces of at most
this many, near-equal: every poll holds the waiting readers up for its transaction, and INVT's
default 12-word read of the running values held them 30 ms at 19200 baud against a 2-word
read's 17 (a reader's p99 1.20-1.21x of the same load unpolled); two 6-word reads hold them
about 23 ms each, one reader's round apart (`gateway.bus.queue`)."""


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

    def pieces_while_reads_wait(self) -> tuple[PollBlock, ...]:
        """This block as reads of at most `WORDS_WHILE_READS_WAIT` words, near-equal, in
        order; itself when it is that short, or a block of bits (a coil read's length is
        bits, a few bytes on the wire)."""
        if self.table.bits or self.count <= WORDS_WHILE_READS_WAIT:
            return (self,)
        number = -(-self.count // WORDS_WHILE_READS_WAIT)
        size, longer = divmod(self.count, number)
        pieces, start = [], self.start
        for index in range(number):
            count = size + (index < longer)
            pieces.append(PollBlock(start, count, self.table))
            start += count
        return tuple(pieces)


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
