"""Report by exception: a device's reading is news when a point moved beyond its deadband,
no sooner than its minimum interval, or its maximum interval passed."""

from __future__ import annotations

from gateway.profile.point_types import Kind, ReportRule, Table, TypedPoint
from gateway.profile.report_by_exception import ExceptionReport


def report(**rule: float) -> ExceptionReport:
    level = TypedPoint("level", Table.INPUT, 0, Kind.F32, 2, report=ReportRule(**rule))
    mode = TypedPoint("mode", Table.HOLDING, 0, Kind.ENUM, values={0: "off", 1: "on"})
    return ExceptionReport([level, mode])


def test_without_rules_any_change_is_news() -> None:
    rbe = report()
    assert rbe.news({"level": 10.0, "mode": "off"}, 0.0)  # never published
    rbe.published({"level": 10.0, "mode": "off"}, 0.0)
    assert not rbe.news({"level": 10.0, "mode": "off"}, 1.0)
    assert rbe.news({"level": 10.001, "mode": "off"}, 1.0)
    assert rbe.news({"level": 10.0, "mode": "on"}, 1.0)


def test_an_absolute_deadband_counts_from_the_value_last_published() -> None:
    rbe = report(deadband=0.5)
    rbe.published({"level": 10.0, "mode": "off"}, 0.0)
    assert not rbe.news({"level": 10.4, "mode": "off"}, 1.0)
    assert not rbe.news({"level": 9.5, "mode": "off"}, 2.0)  # exactly the deadband: not beyond
    assert rbe.news({"level": 10.6, "mode": "off"}, 3.0)  # a drift that added up


def test_a_percent_deadband_is_of_the_value_last_published() -> None:
    rbe = report(deadband_percent=2.0)
    rbe.published({"level": 200.0}, 0.0)
    assert not rbe.news({"level": 203.9}, 1.0)
    assert rbe.news({"level": 204.1}, 1.0)


def test_min_interval_holds_a_change_back_and_max_interval_sends_a_quiet_one() -> None:
    rbe = report(min_interval_s=5.0, max_interval_s=30.0)
    rbe.published({"level": 1.0}, 0.0)
    assert not rbe.news({"level": 2.0}, 4.9)
    assert rbe.news({"level": 2.0}, 5.0)
    assert not rbe.news({"level": 1.0}, 29.0)
    assert rbe.news({"level": 1.0}, 30.0)


def test_an_unread_point_is_no_news() -> None:
    rbe = report()
    rbe.published({"mode": "off"}, 0.0)
    assert not rbe.news({"mode": "off"}, 1.0)
