"""What the gateway knows of one drive from its polls: raw registers, availability, events.

The state changes only here, and each change that a dashboard must hear about as it happens (a
fault raised or cleared, the drive lost or back, a device's point beyond its limit or back)
comes back from the method that made it, as a `DriveEvent`.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum

from gateway.profile import DriveProfile
from gateway.profile.limit_alarms import LimitAlarms, point_limits
from gateway.profile.point_types import Limit
from gateway.profile.telemetry import Telemetry


class EventKind(StrEnum):
    FAULT_RAISED = "fault_raised"
    FAULT_CLEARED = "fault_cleared"
    DRIVE_OFFLINE = "drive_offline"
    DRIVE_ONLINE = "drive_online"
    ALARM_RAISED = "alarm_raised"
    ALARM_CLEARED = "alarm_cleared"
    """A device file's point or a drive's telemetry key beyond its limit, or back inside
    (`gateway.profile.limit_alarms`)."""


@dataclass(frozen=True, slots=True)
class DriveEvent:
    kind: EventKind
    drive: str
    data: Telemetry = field(default_factory=dict)
    at: float = field(default_factory=time.time)
    """Wall-clock time (epoch seconds) the gateway noticed it."""
    snapshot: Telemetry = field(default_factory=dict)
    """For a raised fault: the drive's telemetry as last polled, at the moment it was raised."""


class DriveState:
    def __init__(
        self, name: str, profile: DriveProfile, limits: Mapping[str, Limit] | None = None
    ) -> None:
        self.name = name
        self.profile = profile
        self.registers: dict[int, int] = {}
        self.online: bool | None = None
        """None until the first poll has answered or failed."""
        self.last_seen: float | None = None
        """Wall-clock time of the last poll the drive answered."""
        self.alarms = LimitAlarms.of_keys(
            point_limits(profile.typed_points) if limits is None else limits
        )
        """A drive's on its telemetry keys (`drives[].alarms`), a device's on its points; the
        state carries each one's flag (Home Assistant's binary sensor)."""
        self.fault_before_start: int | None = None
        """The fault the last run left open for this drive (from the store): its first poll
        compares with it, so a fault still there after a restart is not raised again, and one
        cleared meanwhile is cleared."""

    def record_poll(self, start: int, words: Sequence[int], at: float) -> list[DriveEvent]:
        """A poll answered: store its words; the events it caused (fault, back online)."""
        fault_before = self.profile.current_fault(self.registers)
        for offset, word in enumerate(words):
            self.registers[start + offset] = word
        self.last_seen = at
        events = self.set_online(True)
        fault_now = self.profile.current_fault(self.registers)
        if fault_now is not None and fault_before is None:
            # The fault word's first poll: compared with what the last run left open, if any.
            fault_before, self.fault_before_start = self.fault_before_start, None
        if fault_now is not None and fault_now != (fault_before or 0):
            events += self._fault_changed(fault_before or 0, fault_now)
        if self.alarms.watching:
            reading = self.profile.telemetry(self.registers)
            for change in self.alarms.check(reading, time.monotonic()):
                kind = EventKind.ALARM_RAISED if change.raised else EventKind.ALARM_CLEARED
                events.append(DriveEvent(kind, self.name, change.data(), at))
        return events

    def set_online(self, online: bool) -> list[DriveEvent]:
        was = self.online
        self.online = online
        if online and was is False:
            return [DriveEvent(EventKind.DRIVE_ONLINE, self.name)]
        if not online and was is not False:
            # A drive never seen is reported too: it is configured, so somebody expects it.
            return [DriveEvent(EventKind.DRIVE_OFFLINE, self.name)]
        return []

    def telemetry(self) -> Telemetry:
        telemetry = self.profile.telemetry(self.registers)
        if self.alarms.watching:
            telemetry.update(self.alarms.active(telemetry))
        if self.last_seen is not None:
            telemetry["last_seen"] = iso_time(self.last_seen)
        return telemetry

    def _fault_changed(self, before: int, now: int) -> list[DriveEvent]:
        events = []
        if before:
            cleared = self.profile.fault_fields(before)
            events.append(DriveEvent(EventKind.FAULT_CLEARED, self.name, cleared))
        if now:
            raised = self.profile.fault_fields(now)
            snapshot = self.telemetry()
            events.append(DriveEvent(EventKind.FAULT_RAISED, self.name, raised, snapshot=snapshot))
        return events


def iso_time(epoch_s: float) -> str:
    """UTC with milliseconds, as Zigbee2MQTT writes `last_seen`: 2024-05-01T12:00:00.250Z."""
    whole = time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(epoch_s))
    return f"{whole}.{int(epoch_s * 1000) % 1000:03d}Z"
