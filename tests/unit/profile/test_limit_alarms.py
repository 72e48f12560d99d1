"""Limit alarms: raised beyond a limit after its delay, cleared back inside by more than the
hysteresis after the same delay; one alarm however long the value hovers at the limit."""

from __future__ import annotations

from gateway.profile.limit_alarms import AlarmChange, LimitAlarms
from gateway.profile.point_types import Kind, Limit, Table, TypedPoint


def alarms(**limit: float) -> LimitAlarms:
    level = TypedPoint("level", Table.INPUT, 0, Kind.F32, 2, limit=Limit(**limit))
    return LimitAlarms([level])


def test_a_high_limit_with_hysteresis() -> None:
    watch = alarms(high=80.0, hysteresis=5.0)
    assert watch.check({"level": 80.0}, 0.0) == []  # at the limit is not beyond it
    assert watch.check({"level": 81.0}, 1.0) == [AlarmChange("level", "high", True, 81.0, 80.0)]
    assert watch.check({"level": 79.0}, 2.0) == []  # back, but not by the hysteresis
    assert watch.check({"level": 90.0}, 3.0) == []  # still the same alarm
    assert watch.check({"level": 74.9}, 4.0) == [AlarmChange("level", "high", False, 74.9, 80.0)]


def test_a_low_limit_waits_for_its_delay_both_ways() -> None:
    watch = alarms(low=10.0, delay_s=5.0)
    assert watch.check({"level": 9.0}, 0.0) == []
    assert watch.check({"level": 11.0}, 3.0) == []  # back before the delay: the wait restarts
    assert watch.check({"level": 9.0}, 4.0) == []
    assert watch.check({"level": 8.0}, 8.9) == []
    assert watch.check({"level": 8.0}, 9.0) == [AlarmChange("level", "low", True, 8.0, 10.0)]
    assert watch.check({"level": 12.0}, 10.0) == []
    assert watch.check({"level": 12.0}, 15.0) == [AlarmChange("level", "low", False, 12.0, 10.0)]


def test_an_unread_point_changes_nothing() -> None:
    watch = alarms(high=1.0)
    assert watch.check({}, 0.0) == []
    assert AlarmChange("level", "high", True, 2.0, 1.0).data() == {
        "point": "level",
        "limit": "high",
        "value": 2.0,
        "threshold": 1.0,
    }
