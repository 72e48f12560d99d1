"""The whole file's model: its sections, and the checks across them run once every section is
valid (`cross_checks`)."""

from __future__ import annotations

from pydantic import Field, model_validator

from gateway.config.cross_checks import cross_field_problems
from gateway.config.sections import (
    BusConfig,
    ConsoleConfig,
    DriveConfig,
    LoggingConfig,
    MetricsConfig,
    ModbusTcpConfig,
    MqttConfig,
    Section,
    StorageConfig,
)


class GatewayConfig(Section):
    version: int | None = None
    """The file format's version (see `CONFIG_VERSIONS`); a file without it is read as version 1."""
    gateway_id: str = Field("invt-gateway", min_length=1, pattern=r"^[A-Za-z0-9_-]+$")
    modbus_tcp: ModbusTcpConfig = ModbusTcpConfig()
    buses: tuple[BusConfig, ...]
    drives: tuple[DriveConfig, ...] = ()
    mqtt: MqttConfig | None = None
    metrics: MetricsConfig = MetricsConfig()
    console: ConsoleConfig = ConsoleConfig()
    logging: LoggingConfig = LoggingConfig()
    storage: StorageConfig = StorageConfig()

    @model_validator(mode="after")
    def _cross_checks(self) -> GatewayConfig:
        problems = cross_field_problems(self.buses, self.drives, self.modbus_tcp.access)
        if problems:
            raise ValueError("\n".join(problems))
        return self

    def drive_by_unit_id(self) -> dict[int, DriveConfig]:
        return {d.effective_unit_id: d for d in self.drives}
