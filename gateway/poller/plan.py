"""What to read from a drive and how often: poll groups cut into requests the drive accepts.

A group comes from the YAML (`drives[].poll`) or, when the drive has none, from its profile
(state words and fault code every 0.5 s, the running values 3000H-300BH every 2 s on INVT). INVT
drives answer at most 16 words per 03H request, so a group is read as several blocks of at most
the profile's `max_words`, each one request on the bus.
"""

from __future__ import annotations

from dataclasses import dataclass

from gateway.settings import DriveSettings


@dataclass(frozen=True, slots=True)
class PollBlock:
    """One 03H request: `count` words from `start`."""

    start: int
    count: int


@dataclass(frozen=True, slots=True)
class PollSchedule:
    group: str
    interval_s: float
    blocks: tuple[PollBlock, ...]


def poll_schedules(drive: DriveSettings) -> tuple[PollSchedule, ...]:
    max_words = drive.profile.max_words
    return tuple(
        PollSchedule(g.name, g.interval_s, blocks(g.start, g.count, max_words))
        for g in drive.poll_groups
    )


def blocks(start: int, count: int, max_words: int) -> tuple[PollBlock, ...]:
    return tuple(
        PollBlock(start + offset, min(max_words, count - offset))
        for offset in range(0, count, max_words)
    )
