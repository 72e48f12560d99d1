"""The MQTT bridge's settings: the broker, its topics, Home Assistant discovery, commands."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from gateway.config import (
    DriveReportConfig,
    GatewayConfig,
    MqttConfig,
    ReportConfig,
    SparkplugConfig,
)
from gateway.profile.point_types import Reporting


@dataclass(frozen=True, slots=True)
class DriveReporting:
    """One drive's report by exception: the rule of its keys, and of the keys set apart."""

    default: Reporting = field(default_factory=Reporting)
    keys: Mapping[str, Reporting] = field(default_factory=dict)


@dataclass(frozen=True, slots=True)
class SparkplugSettings:
    """The edge node's names in the `spBv1.0` namespace (`mqtt.sparkplug`)."""

    group_id: str
    edge_node_id: str
    primary_host_id: str | None = None


@dataclass(frozen=True, slots=True)
class MqttSettings:
    gateway_id: str
    client_id: str
    """Unique per gateway: two with the same id would throw each other off the broker."""
    servers: tuple[tuple[str, int], ...]
    """The brokers (host, port) tried in turn: a cluster's nodes, or the one `host`/`port`."""
    username: str | None
    password: str | None
    tls: bool
    ca_file: str | None
    cert_file: str | None
    key_file: str | None
    keepalive_s: int
    reconnect_max_s: float
    base_topic: str
    homeassistant_discovery: bool
    discovery_prefix: str
    publish_interval_s: float
    command_max_age_s: float
    commands_enabled: bool
    publish_qos: int = 1
    """QoS of all but events: states, availabilities, info, answers (`mqtt.publish_qos`)."""
    own_events_connection: bool = False
    """The event log forwarded on a connection of its own (`mqtt.own_events_connection`)."""
    reporting: Mapping[str, DriveReporting] = field(default_factory=dict)
    """Drive → its report by exception (`mqtt.report` under its own `report`); a device file's
    points carry theirs."""
    device_reporting: Reporting = field(default_factory=Reporting)
    """Every device's report by exception (`mqtt.report.devices`), under what its device file
    and its points say."""
    sparkplug: SparkplugSettings | None = None
    """The Sparkplug B edge node beside the JSON topics; None: not enabled."""


def mqtt_settings(config: GatewayConfig) -> MqttSettings | None:
    """The bridge's settings; None when MQTT is left out or not enabled."""
    mqtt: MqttConfig | None = config.mqtt
    if mqtt is None or not mqtt.enabled:
        return None
    return MqttSettings(
        gateway_id=config.gateway_id,
        client_id=mqtt.client_id or f"invt-gateway-{config.gateway_id}",
        servers=mqtt.broker_addresses(),
        username=mqtt.username,
        password=mqtt.password,
        tls=mqtt.tls,
        ca_file=mqtt.ca_file,
        cert_file=mqtt.cert_file,
        key_file=mqtt.key_file,
        keepalive_s=mqtt.keepalive_s,
        reconnect_max_s=mqtt.reconnect_max_s,
        base_topic=mqtt.base_topic,
        homeassistant_discovery=mqtt.homeassistant_discovery,
        discovery_prefix=mqtt.discovery_prefix,
        publish_interval_s=mqtt.publish_interval_s,
        command_max_age_s=mqtt.command_max_age_s,
        commands_enabled=mqtt.commands_enabled,
        publish_qos=mqtt.publish_qos,
        own_events_connection=mqtt.own_events_connection,
        reporting={d.name: _drive_reporting(mqtt.report, d.report) for d in config.drives},
        device_reporting=_rule(mqtt.report.devices),
        sparkplug=_sparkplug(mqtt.sparkplug, config.gateway_id),
    )


def _sparkplug(config: SparkplugConfig | None, gateway_id: str) -> SparkplugSettings | None:
    if config is None or not config.enabled:
        return None
    return SparkplugSettings(
        group_id=config.group_id,
        edge_node_id=config.edge_node_id or gateway_id,
        primary_host_id=config.primary_host_id,
    )


def _drive_reporting(gateway: ReportConfig, drive: DriveReportConfig | None) -> DriveReporting:
    default = _layered(gateway, drive)
    keys = drive.keys if drive is not None else {}
    return DriveReporting(
        _rule(default), {key: _rule(_layered(default, own)) for key, own in keys.items()}
    )


def _layered(under: ReportConfig, over: ReportConfig | None) -> ReportConfig:
    """`over`'s keys where it sets them, `under`'s elsewhere."""
    if over is None:
        return under
    return under.model_copy(update=over.model_dump(exclude_none=True, exclude={"keys"}))


def _rule(config: ReportConfig) -> Reporting:
    max_ms = config.max_interval_ms
    return Reporting(
        deadband=config.deadband or 0.0,
        deadband_percent=config.deadband_percent or 0.0,
        min_interval_s=(config.min_interval_ms or 0.0) / 1000,
        max_interval_s=None if max_ms is None else max_ms / 1000,
    )
