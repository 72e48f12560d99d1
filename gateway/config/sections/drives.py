"""`drives`: each drive (or other Modbus device) on a line, its model and the corrections to its
profile, its poll groups, report by exception and limit alarms."""

from __future__ import annotations

from typing import TYPE_CHECKING, Annotated

from pydantic import Field, field_validator, model_validator

from gateway.config.sections.reports import DriveReportConfig
from gateway.config.sections.section import Section
from gateway.config.sections.values import Word

if TYPE_CHECKING:
    from gateway.profile import DriveProfile


class PollGroupConfig(Section):
    name: str = Field(min_length=1)
    """The group's name (in logs and metrics)."""
    start: int = Field(ge=0, le=0xFFFF)
    """The first register read (`0x2100`)."""
    count: int = Field(ge=1, le=125)
    """How many registers from `start` one read takes."""
    interval_ms: float = Field(gt=0)
    """How often the group is read."""


class AlarmConfig(Section):
    """A limit alarm on one of a drive's telemetry keys (`gateway.profile.limit_alarms`)."""

    high: float | None = None
    """Raised when the value stays above this for `delay_ms`."""
    low: float | None = None
    """Raised when the value stays below this for `delay_ms`."""
    hysteresis: float = Field(0.0, ge=0)
    """How far back inside the limit the value must come for the alarm to clear."""
    delay_ms: float = Field(0.0, ge=0)
    """How long beyond (or back inside) before the alarm changes."""

    @model_validator(mode="after")
    def _limits(self) -> AlarmConfig:
        if self.high is None and self.low is None:
            raise ValueError("an alarm needs a high or a low limit (or both)")
        if self.high is not None and self.low is not None and self.low >= self.high:
            raise ValueError(f"low ({self.low}) must be below high ({self.high})")
        return self


class DriveConfig(Section):
    name: str = Field(min_length=1, pattern=r"^[A-Za-z0-9_-]+$")
    """Also the drive's MQTT topic, so no spaces, slashes or wildcards."""
    bus: str
    """The `name` of the bus the drive is on."""
    address: int = Field(ge=1, le=247)
    """The drive's Modbus address on its line, 1..247 (INVT P14.00)."""
    unit_id: int | None = Field(None, ge=1, le=255)
    """The Modbus-TCP unit id SCADA uses; defaults to the address."""
    model: str = "gd20"
    """The drive's series or device (see Drive series): gd20 gd200a gd300 gd300l gd30 ipe300
    gd350 gd350ul gd350a gd10 gd35 gd100 acs355 acs580 generic, a shipped device file (sdm630,
    analog_input_4_20ma) or `file:PATH` for a site's own (see Other Modbus devices)."""
    timeout_ms: float | None = Field(None, gt=0, le=60000)
    """This drive's response timeout, over its bus's `timeout_ms`; default the bus's."""
    retries: int | None = Field(None, ge=0, le=10)
    """This drive's retries, over its bus's `retries`; default the bus's."""
    split: bool | None = None
    """Split reads and writes over the model's word limit (16 on INVT); default per model."""
    ram_writes: bool = False
    """Send 06H/10H writes of P-parameters to the RAM-only address (no EEPROM wear)."""
    cache_max_age_ms: float | None = Field(None, gt=0)
    """Answer SCADA reads inside a polled range from the poll cache when no older than this."""
    poll: tuple[PollGroupConfig, ...] | None = None
    """Poll groups; default from the model's profile."""
    identification: tuple[Word, ...] | None = None
    """Codes this drive answers at 2103H ("01F0H"), where the profile's are unconfirmed."""
    faults: dict[Annotated[int, Field(ge=1, le=0xFFFF)], str] | None = None
    """Fault names this drive's series uses where the profile's table is wrong or unconfirmed:
    code → "SHORT: description" (e.g. `40: "BRKE: brake feedback fault"`)."""
    ready_bit_set_means_ready: bool | None = None
    """The polarity of state word 2 bit 0 where the profile's is unconfirmed."""
    report: DriveReportConfig | None = None
    """When its state is worth publishing on MQTT (report by exception); a device file's
    points carry their own rules, in the file."""
    alarms: dict[str, AlarmConfig] = Field(default_factory=dict)
    """Limit alarms: telemetry key (`output_current_a`, `bus_voltage_v`) → its limits."""

    @property
    def effective_unit_id(self) -> int:
        return self.address if self.unit_id is None else self.unit_id

    def profile(self) -> DriveProfile:
        """The model's profile with this drive's corrections applied."""
        from gateway.profile import get_profile

        return get_profile(self.model).with_overrides(
            identification=self.identification,
            faults=self.faults,
            ready_bit_set_means_ready=self.ready_bit_set_means_ready,
        )

    @field_validator("model")
    @classmethod
    def _model(cls, value: str) -> str:
        from gateway.profile import get_profile  # the profile package owns the model names

        get_profile(value)
        return value

    @model_validator(mode="after")
    def _overrides(self) -> DriveConfig:
        """The corrections given apply to the model (an ABB drive has no 2103H code)."""
        self.profile()  # ValueError naming the key that doesn't apply
        return self

    @model_validator(mode="after")
    def _telemetry_keys(self) -> DriveConfig:
        """`report` and `alarms` name telemetry keys the drive has; a device's are in its file."""
        if self.report is None and not self.alarms:
            return self
        profile = self.profile()
        if profile.typed_points:
            section = "report" if self.report is not None else "alarms"
            raise ValueError(f"{section}: a device's points set theirs in its device file")
        named = {"alarms": tuple(self.alarms)}
        if self.report is not None:
            named["report.keys"] = tuple(self.report.keys)
        known = profile.telemetry_keys
        for where, keys in named.items():
            for key in keys:
                if key not in known:
                    shown = ", ".join(sorted(known))
                    raise ValueError(
                        f"{where}.{key}: not a telemetry key of {self.model} ({shown})"
                    )
        return self
