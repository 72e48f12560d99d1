"""The MQTT bridge's settings: the broker, its topics, Home Assistant discovery, commands."""

from __future__ import annotations

from dataclasses import dataclass

from gateway.config import GatewayConfig, MqttConfig


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
    )
