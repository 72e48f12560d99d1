"""How much of a line its polls take: the wire time of every planned read, per second.

A read request is 8 bytes (address, function, start, count, CRC); its reply 5 bytes around the
data (2 per register, 1 per 8 bits); each frame is followed by the t3.5 silence. Each device's
own delay before it answers comes on top, and the line's SCADA traffic too: what is left of the
line for them is what `check-config` reports.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Final

from gateway.modbus.timing import CharacterFormat
from gateway.poller.plan import PollBlock, PollSchedule

REQUEST_BYTES: Final = 8
REPLY_OVERHEAD_BYTES: Final = 5


@dataclass(frozen=True, slots=True)
class PollLoad:
    requests_per_s: float
    busy_fraction: float
    """The share of the line's time the polls' frames and silences take (1.0: all of it)."""


def block_time_s(block: PollBlock, line: CharacterFormat) -> float:
    data = -(-block.count // 8) if block.table.bits else 2 * block.count
    frames = REQUEST_BYTES + REPLY_OVERHEAD_BYTES + data
    return line.wire_time_s(frames) + 2 * line.t35_s


def poll_load(schedules: Iterable[PollSchedule], line: CharacterFormat) -> PollLoad:
    requests = busy = 0.0
    for schedule in schedules:
        requests += len(schedule.blocks) / schedule.interval_s
        busy += sum(block_time_s(b, line) for b in schedule.blocks) / schedule.interval_s
    return PollLoad(requests, busy)
