"""Report by exception (`drives[].report`, `mqtt.report`): when a state is worth publishing."""

from __future__ import annotations

from pydantic import Field

from gateway.config.sections.section import Section


class ReportConfig(Section):
    """Report by exception: when a drive's state is worth publishing. A key left out takes the
    next level's (a telemetry key's → its drive's `report` → `mqtt.report` → publish on any
    change, and every `mqtt.publish_interval_s`: the behaviour before these keys existed; a
    device's point's → its device file's → `mqtt.report.devices` → the same)."""

    deadband: float | None = Field(None, ge=0)
    """A number must move by more than this (in its unit) since it was last published."""
    deadband_percent: float | None = Field(None, ge=0)
    """... and by more than this share of the value last published."""
    min_interval_ms: float | None = Field(None, ge=0)
    """A change is published no sooner than this after the key was last published."""
    max_interval_ms: float | None = Field(None, gt=0)
    """Published at least this often, changed or not (default: `mqtt.publish_interval_s`)."""


class DriveReportConfig(ReportConfig):
    """A drive's `report`: its defaults, and `keys` (telemetry key → its own rule)."""

    keys: dict[str, ReportConfig] = Field(default_factory=dict)
    """Telemetry key (`output_current_a`) → its own rule, over the drive's."""


class GatewayReportConfig(ReportConfig):
    """`mqtt.report`: every drive's defaults, and `devices`, every device's (a device file's
    own keys, and its points', override them; its points' units differ from a drive's, so a
    drive's deadband is not theirs)."""

    devices: ReportConfig = ReportConfig()
    """Every device's report by exception, unless its device file or point says otherwise (a
    drive's deadbands are not a meter's)."""
