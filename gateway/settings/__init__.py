"""The one place a loaded configuration becomes runtime settings.

`runtime_settings` turns a validated `GatewayConfig` into frozen dataclasses, one per feature:
the buses and drives (`lines`), Modbus-TCP (`tcp`), MQTT (`mqtt`), the store, metrics and the
console (`local`). Units are converted here (milliseconds to seconds), defaults resolved (a
drive's unit id and poll groups, the MQTT client id, the store's path). The features take their
settings and never see the configuration's models; only this package (besides the configuration
itself, the commands that load a file, and reload's planning) imports `gateway.config`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

from gateway.bus import BusSettings
from gateway.config import GatewayConfig
from gateway.settings.lines import DriveSettings, bus_settings, drive_route, drive_settings
from gateway.settings.local import (
    ConsoleSettings,
    ConsoleUser,
    MetricsSettings,
    StoreSettings,
    console_settings,
    metrics_settings,
    store_settings,
)
from gateway.settings.mqtt import MqttSettings, mqtt_settings
from gateway.settings.opcua import OpcUaSettings, opcua_settings
from gateway.settings.redundancy import RedundancySettings, redundancy_settings
from gateway.settings.shown import shown_configuration
from gateway.settings.tcp import tcp_settings
from gateway.tcp import TcpSettings


@dataclass(frozen=True, slots=True)
class GatewaySettings:
    source: GatewayConfig
    """The configuration these were made from: what a reload compares a new file with."""
    gateway_id: str
    buses: tuple[BusSettings, ...]
    drives: tuple[DriveSettings, ...]
    tcp: TcpSettings
    store: StoreSettings
    mqtt: MqttSettings | None
    """None: MQTT left out or not enabled."""
    metrics: MetricsSettings | None
    console: ConsoleSettings | None
    log_level: str
    """Python's name of the level ("INFO")."""
    opcua: OpcUaSettings | None = None
    """None: the OPC UA server not enabled."""
    redundancy: RedundancySettings | None = None
    """None: no redundancy, this gateway is the line's only master."""

    def shown_configuration(self) -> dict[str, Any]:
        """The running configuration, secrets masked (`gateway.settings.shown`)."""
        return shown_configuration(self.source)

    def polled(self, drive: DriveSettings) -> bool:
        """Without MQTT or the console only the drives that ask for it are polled: polls cost
        line time, and a pure Modbus-TCP gateway shouldn't spend it unasked."""
        shown = self.mqtt is not None or self.console is not None or self.opcua is not None
        return shown or drive.asks_for_polls

    def drive(self, name: str) -> DriveSettings:
        return next(d for d in self.drives if d.name == name)


def runtime_settings(config: GatewayConfig) -> GatewaySettings:
    buses = tuple(bus_settings(b) for b in config.buses)
    drives = tuple(drive_settings(d) for d in config.drives)
    settings = GatewaySettings(
        source=config,
        gateway_id=config.gateway_id,
        buses=buses,
        drives=drives,
        tcp=tcp_settings(config.modbus_tcp),
        store=store_settings(config),
        mqtt=mqtt_settings(config),
        metrics=metrics_settings(config.metrics),
        console=console_settings(config.console),
        log_level=config.logging.level.upper(),
        opcua=opcua_settings(config),
    )
    polled = [d for d in drives if settings.polled(d)]
    redundancy = redundancy_settings(config, buses, polled)
    if redundancy is None:
        return settings
    return replace(settings, redundancy=redundancy)


__all__ = [
    "ConsoleSettings",
    "ConsoleUser",
    "DriveSettings",
    "GatewaySettings",
    "MetricsSettings",
    "MqttSettings",
    "OpcUaSettings",
    "StoreSettings",
    "bus_settings",
    "drive_route",
    "drive_settings",
    "mqtt_settings",
    "runtime_settings",
    "tcp_settings",
]
