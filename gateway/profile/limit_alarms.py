"""Limit alarms on a device's points: high and low limits with hysteresis and a delay. No I/O.

A point's alarm is raised when its value has stayed beyond the limit (above `high`, below `low`)
for `delay_s`, and cleared when it has stayed back inside by more than `hysteresis` for as long:
a value hovering at the limit raises one alarm, not one per poll. Each change comes back as an
`AlarmChange` for the poller to turn into an `alarm_raised` / `alarm_cleared` event. A drive's
alarms are on its telemetry keys (`drives[].alarms`), a device's on its points (`point_limits`);
the state of either carries each alarm's flag (`alarm_name`), for Home Assistant's binary sensor.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Literal

from gateway.profile.point_types import Limit, TypedPoint

Side = Literal["high", "low"]


@dataclass(frozen=True, slots=True)
class AlarmChange:
    point: str
    side: Side
    raised: bool
    value: float
    limit: float

    def data(self) -> dict[str, str | float]:
        """The event's data: {"point": "flow", "limit": "high", "value": 12.5, "threshold": 12}."""
        return {
            "point": self.point,
            "limit": self.side,
            "value": self.value,
            "threshold": self.limit,
        }


@dataclass(slots=True)
class _Watch:
    point: str
    side: Side
    limit: float
    hysteresis: float
    delay_s: float
    active: bool = False
    since: float | None = None
    """When the value last crossed to the other side of where the alarm stands (None: it
    hasn't, or it crossed back)."""

    def beyond(self, value: float) -> bool:
        return value > self.limit if self.side == "high" else value < self.limit

    def back(self, value: float) -> bool:
        if self.side == "high":
            return value < self.limit - self.hysteresis
        return value > self.limit + self.hysteresis

    def check(self, value: float, now: float) -> AlarmChange | None:
        crossing = self.back(value) if self.active else self.beyond(value)
        if not crossing:
            self.since = None
            return None
        if self.since is None:
            self.since = now
        if now - self.since < self.delay_s:
            return None
        self.active, self.since = not self.active, None
        return AlarmChange(self.point, self.side, self.active, value, self.limit)


class LimitAlarms:
    """The limit alarms of one device's points (or one drive's telemetry keys), and where each
    stands."""

    def __init__(self, points: Iterable[TypedPoint]) -> None:
        self._watches: list[_Watch] = []
        for name, limit in point_limits(points).items():
            self._watch(name, limit)

    @classmethod
    def of_keys(cls, limits: Mapping[str, Limit]) -> LimitAlarms:
        """A drive's: its telemetry keys' limits (`drives[].alarms`)."""
        alarms = cls(())
        for key, limit in limits.items():
            alarms._watch(key, limit)
        return alarms

    @property
    def watching(self) -> bool:
        return bool(self._watches)

    def active(self, reading: Mapping[str, object]) -> dict[str, bool]:
        """Each alarm's flag by its name (`alarm_name`): whether it stands now; left out while
        its value is unread (absent rather than guessed)."""
        return {
            alarm_name(watch.point, watch.side): watch.active
            for watch in self._watches
            if watch.point in reading
        }

    def _watch(self, name: str, limit: Limit) -> None:
        for side, threshold in limit_sides(limit):
            self._watches.append(_Watch(name, side, threshold, limit.hysteresis, limit.delay_s))

    def check(self, reading: Mapping[str, object], now: float) -> list[AlarmChange]:
        """The alarms `reading` (point name → value) raises or clears at monotonic `now`."""
        changes = []
        for watch in self._watches:
            value = reading.get(watch.point)
            if isinstance(value, bool) or not isinstance(value, int | float):
                continue  # not read yet
            change = watch.check(float(value), now)
            if change is not None:
                changes.append(change)
        return changes


def point_limits(points: Iterable[TypedPoint]) -> dict[str, Limit]:
    """A device's alarms as a drive's are given: point name → its limits, for the points that
    have a high or a low limit."""
    return {p.name: p.limit for p in points if p.limit.high is not None or p.limit.low is not None}


def limit_sides(limit: Limit) -> list[tuple[Side, float]]:
    """The sides of an alarm that have a limit, each with its threshold."""
    sides: tuple[tuple[Side, float | None], ...] = (("high", limit.high), ("low", limit.low))
    return [(side, at) for side, at in sides if at is not None]


def alarm_name(point: str, side: Side) -> str:
    """The key of an alarm's flag in a drive's state: `output_current_a_high_alarm`."""
    return f"{point}_{side}_alarm"
