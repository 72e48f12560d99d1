"""A drive's report by exception from the file: a telemetry key's rule over its drive's
`report`, over `mqtt.report`, over publishing any change; a key the drive has no telemetry for
refused at load, named."""

from __future__ import annotations

import pytest

from gateway.config import parse_config
from gateway.errors import ConfigError
from gateway.profile.point_types import Reporting
from gateway.settings import runtime_settings

FILE = """
buses: [{name: line1, port: /dev/null}]
mqtt:
  report: {deadband_percent: 2, max_interval_ms: 30000}
drives:
  - {name: pump1, bus: line1, address: 1}
  - name: fan2
    bus: line1
    address: 2
    report:
      min_interval_ms: 500
      keys: {output_current_a: {deadband: 0.5, deadband_percent: 0}}
"""


def test_each_level_overrides_the_one_under_it() -> None:
    mqtt = runtime_settings(parse_config(FILE)).mqtt
    assert mqtt is not None
    pump, fan = mqtt.reporting["pump1"], mqtt.reporting["fan2"]
    assert pump.default == Reporting(deadband_percent=2, max_interval_s=30)
    assert pump.keys == {}
    assert fan.default == Reporting(deadband_percent=2, min_interval_s=0.5, max_interval_s=30)
    assert fan.keys["output_current_a"] == Reporting(
        deadband=0.5, deadband_percent=0, min_interval_s=0.5, max_interval_s=30
    )


def test_without_report_keys_any_change_is_published_as_before() -> None:
    text = "buses: [{name: line1, port: /dev/null}]\nmqtt: {}\n"
    text += "drives: [{name: pump1, bus: line1, address: 1}]\n"
    mqtt = runtime_settings(parse_config(text)).mqtt
    assert mqtt is not None
    assert mqtt.reporting["pump1"].default == Reporting()


def test_a_key_the_drive_has_no_telemetry_for_is_refused_by_name() -> None:
    text = FILE.replace("output_current_a: {", "output_curent_a: {")
    with pytest.raises(ConfigError) as refused:
        parse_config(text)
    assert "report.keys.output_curent_a: not a telemetry key of gd20" in str(refused.value)
