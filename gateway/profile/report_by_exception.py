"""Report by exception: whether a device's or a drive's new reading is worth publishing. No I/O.

A state is one message of all its points (a drive's: its telemetry keys); it goes out when one
point has news:

    changed    a number moved by more than its `deadband` and more than its `deadband_percent`
               of the value last published (any other value: it differs), and the point's
               `min_interval_s` has passed since it was last published
    due        the point's `max_interval_s` has passed since it was last published
    new        the point was never published (or was unread then)

A device's point goes by its device file's rule over the gateway's `mqtt.report.devices`
(`ReportRule`), a drive's key by `mqtt.report` under its own `report`; a device's alarm flags
are news at any change.

Each point's reference is what the last publication carried: a slow drift is published once it
adds up to the deadband, not lost step by step. The gateway's `mqtt.publish_interval_s` still
republishes the whole state however quiet it is.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass

from gateway.profile.point_types import Reporting, TypedPoint, Value

ANY_CHANGE = Reporting()
"""Every change is news (and `mqtt.publish_interval_s` republishes): no rule set anywhere."""


@dataclass(slots=True)
class _Published:
    value: Value
    at: float


class ExceptionReport:
    """What was last published of one device's points (or one drive's keys), and when."""

    def __init__(self, points: Iterable[TypedPoint], under: Reporting = ANY_CHANGE) -> None:
        """A device's: each point by its device file's rule over `under` (the gateway's
        `mqtt.report.devices`); any other key of its state (an alarm's flag) on any change."""
        self._rules = {point.name: point.report.resolved(under) for point in points}
        self._default = ANY_CHANGE
        """The rule of a key `_rules` doesn't name."""
        self._published: dict[str, _Published] = {}

    @classmethod
    def of_keys(cls, default: Reporting, rules: Mapping[str, Reporting]) -> ExceptionReport:
        """A drive's: every key of its readings by `default`, unless `rules` has its own (a
        drive's keys are what its registers give, not a list declared beforehand)."""
        report = cls(())
        report._rules = dict(rules)
        report._default = default
        return report

    def news(self, reading: Mapping[str, object], now: float) -> bool:
        """Whether `reading` (a state: point name → value) has news at monotonic time `now`."""
        return any(
            self._news(name, rule, reading.get(name), now) for name, rule in self._watched(reading)
        )

    def watches(self, name: str) -> bool:
        """Whether `name` has a rule here (a device file's keys beside its points, such as a
        limit alarm's flag, have none)."""
        return name in self._rules or self._default is not None

    def changed(self, reading: Mapping[str, object], now: float) -> list[str]:
        """The points of `reading` with news at `now`: what a message of changes alone carries
        (Sparkplug's DDATA), by the same rules as `news`."""
        return [
            name
            for name, rule in self._watched(reading)
            if self._news(name, rule, reading.get(name), now)
        ]

    def published(self, reading: Mapping[str, object], now: float) -> None:
        """`reading` went out at `now`: each point's new reference."""
        for name, _ in self._watched(reading):
            value = reading.get(name)
            if isinstance(value, int | float | str | bool):
                self._published[name] = _Published(value, now)

    def _watched(self, reading: Mapping[str, object]) -> list[tuple[str, Reporting]]:
        watched = list(self._rules.items())
        watched += [(name, self._default) for name in reading if name not in self._rules]
        return watched

    def _news(self, name: str, rule: Reporting, value: object, now: float) -> bool:
        last = self._published.get(name)
        if value is None:
            return False  # not read yet: nothing to say
        if last is None:
            return True
        since = now - last.at
        if rule.max_interval_s is not None and since >= rule.max_interval_s:
            return True
        return since >= rule.min_interval_s and _moved(rule, last.value, value)


def _moved(rule: Reporting, before: Value, now: object) -> bool:
    numbers = (int, float)
    if isinstance(before, bool) or isinstance(now, bool):
        return before != now
    if not (isinstance(before, numbers) and isinstance(now, numbers)):
        return before != now
    change = abs(now - before)
    return (
        change > 0 and change > rule.deadband and change > abs(before) * rule.deadband_percent / 100
    )
