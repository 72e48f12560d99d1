"""A drive's limit alarms from the file: on telemetry keys it has, with a limit that makes sense;
anything else refused at load, named."""

from __future__ import annotations

import pytest

from gateway.config import parse_config
from gateway.errors import ConfigError
from gateway.profile.point_types import Limit
from gateway.settings import runtime_settings

FILE = """
buses: [{name: line1, port: /dev/null}]
drives:
  - name: pump1
    bus: line1
    address: 1
    alarms:
      output_current_a: {high: 7.5, hysteresis: 0.5, delay_ms: 5000}
"""


def test_an_alarm_becomes_its_limit() -> None:
    (drive,) = runtime_settings(parse_config(FILE)).drives
    assert drive.alarms == {"output_current_a": Limit(high=7.5, hysteresis=0.5, delay_s=5.0)}


@pytest.mark.parametrize(
    ("alarm", "reason"),
    [
        ("output_curent_a: {high: 7.5}", "alarms.output_curent_a: not a telemetry key of gd20"),
        ("output_current_a: {hysteresis: 1}", "an alarm needs a high or a low limit"),
        ("bus_voltage_v: {low: 800, high: 700}", "low (800.0) must be below high (700.0)"),
    ],
)
def test_a_wrong_alarm_is_refused_with_its_reason(alarm: str, reason: str) -> None:
    text = FILE.replace("output_current_a: {high: 7.5, hysteresis: 0.5, delay_ms: 5000}", alarm)
    with pytest.raises(ConfigError) as refused:
        parse_config(text)
    assert reason in str(refused.value)
