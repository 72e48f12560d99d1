"""The whole file's model: its sections, and the checks across them run once every section is
valid (`cross_checks`)."""

from __future__ import annotations

from pydantic import Field, model_validator

from gateway.config.cross_checks import cross_field_problems
from gateway.config.sections.buses import BusConfig
from gateway.config.sections.console import ConsoleConfig
from gateway.config.sections.drives import DriveConfig
from gateway.config.sections.modbus_tcp import ModbusTcpConfig
from gateway.config.sections.monitoring import LoggingConfig, MetricsConfig
from gateway.config.sections.mqtt import MqttConfig
from gateway.config.sections.opcua import OpcUaConfig
from gateway.config.sections.redundancy import RedundancyConfig
from gateway.config.sections.section import Section
from gateway.config.sections.storage import StorageConfig

CONFIG_VERSIONS = (1,)
"""The file format versions this gateway reads (`version:` in the file; without it, 1)."""


class GatewayConfig(Section):
    version: int | None = None
    """The file format's version (see `CONFIG_VERSIONS`); a file without it is read as version 1."""
    gateway_id: str = Field("invt-gateway", min_length=1, pattern=r"^[A-Za-z0-9_-]+$")
    """Unique per gateway: the MQTT client id's and Home Assistant's ids are made from it."""
    modbus_tcp: ModbusTcpConfig = ModbusTcpConfig()
    """The Modbus-TCP server SCADA connects to."""
    buses: tuple[BusConfig, ...]
    """One per RS-485 line; each has its own queue, coroutine and port."""
    drives: tuple[DriveConfig, ...] = ()
    """The drives (and other Modbus devices) on the lines."""
    mqtt: MqttConfig | None = None
    """The broker connection; left out, no MQTT (Modbus-TCP works either way)."""
    metrics: MetricsConfig = MetricsConfig()
    """`/metrics` (Prometheus) and `/health`, on one port."""
    console: ConsoleConfig = ConsoleConfig()
    """The operator's web console (see Console); off unless enabled."""
    opcua: OpcUaConfig = OpcUaConfig()
    """The OPC UA server (see OPC UA); off unless enabled. Its users are `console.users`."""
    logging: LoggingConfig = LoggingConfig()
    """What the log says and in which form."""
    storage: StorageConfig = StorageConfig()
    """The store: events until the broker has them, and the fault history (see Events & fault
    history)."""
    redundancy: RedundancyConfig = RedundancyConfig()
    """An active and a standby gateway on one line (see Redundancy); off unless enabled."""

    @model_validator(mode="after")
    def _cross_checks(self) -> GatewayConfig:
        problems = cross_field_problems(self.buses, self.drives, self.modbus_tcp.access)
        opcua = self.opcua
        if opcua.enabled and not self.console.users and not opcua.anonymous:
            problems.append(
                "opcua: enabled with no console.users and anonymous false: nobody could log in"
            )
        if self.redundancy.enabled and not self._polls_a_drive():
            problems.append(
                "redundancy: enabled, but no drive is polled: a standby tells a live active by "
                "its polls (give a drive `poll` groups, or enable mqtt, the console or opcua)"
            )
        if problems:
            raise ValueError("\n".join(problems))
        return self

    def _polls_a_drive(self) -> bool:
        """Some drive is polled (`GatewaySettings.polled`: every drive once MQTT, the console
        or OPC UA shows values, else those that ask for polls)."""
        shown = (self.mqtt is not None and self.mqtt.enabled) or self.console.enabled
        shown = shown or self.opcua.enabled
        asked = any(d.poll is not None or d.cache_max_age_ms is not None for d in self.drives)
        return bool(self.drives) and (shown or asked)

    def drive_by_unit_id(self) -> dict[int, DriveConfig]:
        return {d.effective_unit_id: d for d in self.drives}
