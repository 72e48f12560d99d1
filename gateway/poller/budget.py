"""How much of a line its polls take: the wire time of every planned read, per second.

A read request is 8 bytes (address, function, start, count, CRC); its reply 5 bytes around the
data (2 per register, 1 per 8 bits); each frame is followed by the t3.5 silence. Each device's
own delay before it answers comes on top, and the line's SCADA traffic too: what is left of the
line for them is what `check-config` reports.

`line_plans` is the one place the planned load is worked out: `check-config` prints it, the
console shows it beside the share each bus and drive took of the line lately.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Final

from gateway.bus import BusSettings
from gateway.modbus.timing import CharacterFormat
from gateway.poller.plan import PollBlock, PollSchedule, poll_schedules
from gateway.settings import DriveSettings, GatewaySettings

REQUEST_BYTES: Final = 8
REPLY_OVERHEAD_BYTES: Final = 5
POLL_BUDGET: Final = 0.7
"""The most of a line's time its planned polls should take: the rest is SCADA's requests, MQTT's
and the console's commands, and the retries of a noisy line. Past it `check-config` warns and
the console marks the line."""


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


@dataclass(frozen=True, slots=True)
class LinePlan:
    """A line's planned poll load, and each polled drive's part of it."""

    total: PollLoad
    drives: Mapping[str, PollLoad]

    @property
    def over_budget(self) -> bool:
        return self.total.busy_fraction > POLL_BUDGET


def line_plans(
    buses: Iterable[BusSettings], polled: Iterable[DriveSettings]
) -> dict[str, LinePlan]:
    """Bus name → the load its `polled` drives' poll plans put on it, at its baud rate."""
    on: dict[str, list[DriveSettings]] = {}
    for drive in polled:
        on.setdefault(drive.bus, []).append(drive)
    plans = {}
    for bus in buses:
        line = bus.line.char_format
        drives = {d.name: poll_load(poll_schedules(d), line) for d in on.get(bus.name, ())}
        total = PollLoad(
            sum(load.requests_per_s for load in drives.values()),
            sum(load.busy_fraction for load in drives.values()),
        )
        plans[bus.name] = LinePlan(total, drives)
    return plans


def line_budget(settings: GatewaySettings) -> tuple[str, list[str]]:
    """Each line's poll load (of the drives `run` would poll), and a warning for each line the
    polls would fill."""
    plans = line_plans(settings.buses, (d for d in settings.drives if settings.polled(d)))
    lines = ["Poll load (wire time of every planned read; each device's answer delay on top):"]
    overloaded = []
    for index, bus in enumerate(settings.buses):
        plan = plans[bus.name]
        load = plan.total
        lines.append(
            f"  {bus.name}: {len(plan.drives)} polled, {load.requests_per_s:.1f} requests/s, "
            f"{load.busy_fraction:.1%} of the line"
        )
        lines += [
            f"    {name}: {drive.requests_per_s:.1f} requests/s, {drive.busy_fraction:.1%}"
            for name, drive in plan.drives.items()
        ]
        if load.busy_fraction >= 1.0:
            overloaded.append(
                f"buses[{index}] ({bus.name}): its polls alone need {load.busy_fraction:.0%} of "
                "the line: polls will fall behind; lengthen intervals (interval_ms) or raise "
                "the baud rate"
            )
        elif plan.over_budget:
            overloaded.append(
                f"buses[{index}] ({bus.name}): its polls take {load.busy_fraction:.0%} of the "
                f"line, more than {POLL_BUDGET:.0%}: little is left for SCADA's requests, "
                "commands and retries; lengthen intervals (interval_ms) or raise the baud rate"
            )
    return "\n".join(lines), overloaded
