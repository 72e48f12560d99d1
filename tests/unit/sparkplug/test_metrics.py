"""A device's metrics: the birth declares them with units and aliases; DDATA carries what has
news by the report-by-exception rules; a key or datatype the birth didn't declare asks for a new
birth; a DCMD's metrics become `/set` payloads."""

from __future__ import annotations

from gateway.profile.models import get_profile
from gateway.profile.point_types import Reporting
from gateway.profile.report_by_exception import ExceptionReport
from gateway.profile.telemetry import Telemetry
from gateway.sparkplug.commands import device_command
from gateway.sparkplug.metrics import Aliases, DeviceMetrics
from gateway.sparkplug.payload import DOUBLE, Received, ReceivedMetric

TELEMETRY: Telemetry = {
    "state": "stopped",
    "fault_code": 0,
    "output_frequency_hz": 0.0,
    "set_frequency_hz": 50.0,
    "output_current_a": 7.3,
    "last_seen": "2026-11-26T01:00:00Z",
}


def device(aliases: Aliases, name: str = "pump1", commands: bool = True) -> DeviceMetrics:
    report = ExceptionReport.of_keys(Reporting(), {"output_current_a": Reporting(deadband=1.0)})
    return DeviceMetrics(name, get_profile("gd350"), report, aliases, commands)


def test_birth_then_changes_by_alias() -> None:
    aliases = Aliases()
    pump = device(aliases)
    born = {m.name: m for m in pump.birth(TELEMETRY, 0.0)}
    assert "last_seen" not in born
    assert born["output_current_a"].properties == {"readOnly": True, "engUnit": "A"}
    assert born["set_frequency_hz"].properties == {"readOnly": False, "engUnit": "Hz"}
    assert born["commands/run_forward"].value is False
    assert pump.changes(TELEMETRY, 1.0) == []
    inside = pump.changes({**TELEMETRY, "output_current_a": 7.9}, 2.0)
    assert inside == []  # inside the 1 A deadband
    moved = pump.changes({**TELEMETRY, "output_current_a": 8.5, "state": "running_forward"}, 3.0)
    assert moved is not None
    assert {(m.alias, m.value) for m in moved} == {
        (born["output_current_a"].alias, 8.5),
        (born["state"].alias, "running_forward"),
    }
    assert next(m.datatype for m in moved if m.value == 8.5) == DOUBLE


def test_aliases_are_the_nodes_and_kept() -> None:
    aliases = Aliases()
    pump, fan = device(aliases), device(aliases, "fan2")
    first = {m.name: m.alias for m in pump.birth(TELEMETRY, 0.0)}
    other = {m.name: m.alias for m in fan.birth(TELEMETRY, 0.0)}
    assert not set(first.values()) & set(other.values())
    pump.forget()
    assert {m.name: m.alias for m in pump.birth(TELEMETRY, 1.0)} == first


def test_a_new_key_or_datatype_asks_for_a_birth() -> None:
    pump = device(Aliases())
    pump.birth(TELEMETRY, 0.0)
    assert pump.changes({**TELEMETRY, "bus_voltage_v": 540.2}, 1.0) is None
    assert pump.changes({**TELEMETRY, "fault_code": "none"}, 1.0) is None
    assert pump.changes({**TELEMETRY, "output_frequency_hz": 1}, 1.0) is not None  # an int fits


def test_dcmd_metrics_as_set_payloads() -> None:
    pump = device(Aliases())
    born = {m.name: m for m in pump.birth(TELEMETRY, 0.0)}
    stop = born["commands/stop"].alias
    asked = Received(
        1_700_000_000_000,
        (
            ReceivedMetric("commands/run_forward", None, 11, True),
            ReceivedMetric("set_frequency_hz", None, 10, 35.0),
            ReceivedMetric("commands/jog_forward", None, 11, False),
            ReceivedMetric(None, stop, 11, True),
            ReceivedMetric("output_current_a", None, 10, 1.0),
            ReceivedMetric("commands/launch", None, 11, True),
        ),
    )
    command = device_command(asked, pump)
    assert command.payloads == [
        {"command": "run_forward", "frequency_hz": 35.0, "time": 1_700_000_000_000}
    ]
    assert command.problems == [
        "commands/stop: one command per DCMD (run_forward came first)",
        "output_current_a: not a writable metric of pump1",
        "commands/launch: pump1 has no such command",
    ]


def test_a_dcmd_whose_name_and_alias_differ_or_whose_value_is_of_another_kind() -> None:
    pump = device(Aliases())
    born = {m.name: m for m in pump.birth(TELEMETRY, 0.0)}
    stop = born["commands/stop"].alias
    asked = Received(
        None,
        (
            ReceivedMetric("commands/run_forward", stop, 11, True),  # which one is meant?
            ReceivedMetric("set_frequency_hz", None, 12, "fast"),
            ReceivedMetric("commands/stop", None, 3, 1),
        ),
    )
    command = device_command(asked, pump)
    assert command.payloads == []
    assert command.problems == [
        f"commands/run_forward: alias {stop} is commands/stop of pump1, not this one",
        "set_frequency_hz: a text for a number metric",
        "commands/stop: a number for a boolean metric",
    ]


def test_a_device_files_writable_point() -> None:
    """An SDM630's `demand_period` (writable in its file) takes a DCMD as `{"point", "value"}`;
    its read-only points don't, and it has no commands to declare."""
    meter = get_profile("sdm630")
    report = ExceptionReport(meter.typed_points)
    metrics = DeviceMetrics("meter1", meter, report, Aliases(), True)
    born = {m.name: m for m in metrics.birth({"demand_period": 15.0, "frequency": 50.0}, 0.0)}
    assert born["demand_period"].properties == {"readOnly": False, "engUnit": "min"}
    assert born["frequency"].properties == {"readOnly": True, "engUnit": "Hz"}
    assert not any(name.startswith("commands/") for name in born)
    asked = Received(
        None,
        (
            ReceivedMetric("demand_period", None, 10, 30.0),
            ReceivedMetric("frequency", None, 10, 60.0),
        ),
    )
    command = device_command(asked, metrics)
    assert command.payloads == [{"point": "demand_period", "value": 30.0}]
    assert command.problems == ["frequency: not a writable metric of meter1"]


def test_a_device_files_alarm_flag_goes_out_when_it_changes() -> None:
    """A device file's points have their own rules; a limit alarm's flag beside them has none,
    and still reaches the host the moment it turns."""
    meter = get_profile("sdm630")
    metrics = DeviceMetrics("meter1", meter, ExceptionReport(meter.typed_points), Aliases(), True)
    reading: Telemetry = {"frequency": 50.0, "frequency_high_alarm": False}
    born = {m.name: m.alias for m in metrics.birth(reading, 0.0)}
    assert metrics.changes(reading, 1.0) == []
    raised = metrics.changes({**reading, "frequency_high_alarm": True}, 2.0)
    assert raised is not None
    assert [(m.alias, m.value) for m in raised] == [(born["frequency_high_alarm"], True)]
    assert metrics.changes({**reading, "frequency_high_alarm": True}, 3.0) == []
