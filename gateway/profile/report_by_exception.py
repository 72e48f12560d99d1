"""Report by exception: whether a device's new reading is worth publishing. No I/O.

A device's state is one message of all its points; it goes out when one point has news:

    changed    a number moved by more than its `deadband` and more than its `deadband_percent`
               of the value last published (any other value: it differs), and the point's
               `min_interval_s` has passed since it was last published
    due        the point's `max_interval_s` has passed since it was last published
    new        the point was never published (or was unread then)

Each point's reference is what the last publication carried: a slow drift is published once it
adds up to the deadband, not lost step by step. The gateway's `mqtt.publish_interval_s` still
republishes the whole state however quiet it is.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass

from gateway.profile.point_types import TypedPoint, Value


@dataclass(slots=True)
class _Published:
    value: Value
    at: float


class ExceptionReport:
    """What was last published of one device's points, and when."""

    def __init__(self, points: Iterable[TypedPoint]) -> None:
        self.points = {point.name: point for point in points}
        self._published: dict[str, _Published] = {}

    def news(self, reading: Mapping[str, object], now: float) -> bool:
        """Whether `reading` (a state: point name → value) has news at monotonic time `now`."""
        return any(self._news(point, reading.get(name), now) for name, point in self.points.items())

    def published(self, reading: Mapping[str, object], now: float) -> None:
        """`reading` went out at `now`: each point's new reference."""
        for name in self.points:
            value = reading.get(name)
            if isinstance(value, int | float | str | bool):
                self._published[name] = _Published(value, now)

    def _news(self, point: TypedPoint, value: object, now: float) -> bool:
        last = self._published.get(point.name)
        if value is None:
            return False  # not read yet: nothing to say
        if last is None:
            return True
        rule = point.reporting
        since = now - last.at
        if rule.max_interval_s is not None and since >= rule.max_interval_s:
            return True
        return since >= rule.min_interval_s and _moved(point, last.value, value)


def _moved(point: TypedPoint, before: Value, now: object) -> bool:
    numbers = (int, float)
    if isinstance(before, bool) or isinstance(now, bool):
        return before != now
    if not (isinstance(before, numbers) and isinstance(now, numbers)):
        return before != now
    change = abs(now - before)
    rule = point.reporting
    return (
        change > 0 and change > rule.deadband and change > abs(before) * rule.deadband_percent / 100
    )
