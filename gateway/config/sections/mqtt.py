"""`mqtt`: the broker connection, the topics, what is published how often, commands, and
Sparkplug B beside the JSON topics."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator, model_validator

from gateway.config.sections.reports import GatewayReportConfig
from gateway.config.sections.section import Section, readable_file

ENV_MQTT_USERNAME = "INVT_GATEWAY_MQTT_USERNAME"
ENV_MQTT_PASSWORD = "INVT_GATEWAY_MQTT_PASSWORD"


_DOT = "RabbitMQ's MQTT plugin turns it into '/', so topics would differ between brokers"


def broker_address(value: str) -> tuple[str, int]:
    """`host:port` (an IPv6 address in brackets, `[::1]:1883`) as its two parts."""
    host, colon, port = value.rpartition(":")
    host = host[1:-1] if host.startswith("[") and host.endswith("]") else host
    if not colon or not host or not port.isdigit() or not 1 <= int(port) <= 65535:
        raise ValueError(f"{value!r} is not host:port (a port 1-65535)")
    return host, int(port)


SPARKPLUG_ID = r"^[A-Za-z0-9_-]+$"
"""A Sparkplug group, edge node or host id: one topic level ('/', '+' and '#' can't be in one,
and '.' would change on RabbitMQ), in the same letters as a drive's name (its device id)."""


class SparkplugConfig(Section):
    """`mqtt.sparkplug`: the gateway as a Sparkplug B edge node, its drives as devices, beside
    the JSON topics (both run on one broker, each on its own connection)."""

    enabled: bool = True
    """False: the section stays in the file, and no Sparkplug (the JSON topics go on)."""
    group_id: str = Field(min_length=1, max_length=64, pattern=SPARKPLUG_ID)
    """The Sparkplug group the edge node is in: the second level of its topics
    (`spBv1.0/<group_id>/...`)."""
    edge_node_id: str | None = Field(None, min_length=1, max_length=64, pattern=SPARKPLUG_ID)
    """Default: the gateway's `gateway_id`."""
    primary_host_id: str | None = Field(None, min_length=1, max_length=64, pattern=SPARKPLUG_ID)
    """The host application whose `spBv1.0/STATE/<id>` says when the edge node may publish;
    None: publish whenever connected."""


class MqttConfig(Section):
    enabled: bool = True
    """False: the section stays in the file, and no MQTT."""
    host: str = "127.0.0.1"
    """The broker's address (or `servers` for several)."""
    port: int = Field(1883, ge=1, le=65535)
    """The broker's port (8883 is usual with TLS)."""
    servers: tuple[str, ...] | None = None
    """`host:port` of each broker (a cluster's nodes), tried in turn; instead of host/port."""
    username: str | None = None
    """Or the environment variable INVT_GATEWAY_MQTT_USERNAME."""
    password: str | None = None
    """Better from the environment variable INVT_GATEWAY_MQTT_PASSWORD than in the file."""
    tls: bool = False
    """Connect to the broker over TLS."""
    ca_file: str | None = None
    """The CA that signs the broker's certificate; default the system's (needs `tls: true`)."""
    cert_file: str | None = None
    """The gateway's client certificate, where the broker asks for one (needs `tls: true`)."""
    key_file: str | None = None
    """The key of `cert_file`."""
    client_id: str | None = None
    """The MQTT client id; default `invt-gateway-<gateway_id>`."""
    base_topic: str = Field("invt", min_length=1)
    """The first level of every topic (`invt/pump1/state`); no `+`, `#`, `.` or empty level."""
    keepalive_s: int = Field(30, ge=5, le=3600)
    """MQTT keep-alive: the broker drops a gateway silent for 1.5 times this."""
    homeassistant_discovery: bool = True
    """Publish Home Assistant discovery messages for every drive."""
    discovery_prefix: str = "homeassistant"
    """The topic prefix Home Assistant listens on for discovery."""
    publish_interval_s: float = Field(60.0, gt=0)
    """A drive's state is published on change and at least this often."""
    publish_qos: Literal[0, 1] = 1
    """QoS of everything the gateway publishes but events (those are QoS 1 always, from the
    store): the retained messages it keeps up to date itself (drive states and availabilities,
    `bridge/info`, `bridge/state`'s "online", discovery), published again on every connection,
    a state at least every `publish_interval_s`, the latest winning; and command answers, never
    sent again after a lost connection anyway. Set 0 on a NATS cluster: there a QoS 1 message
    is also stored in a replicated stream, and for seconds after a node's death (the stream
    elects a leader) NATS holds each such publish 4 s, then closes the connection."""
    own_events_connection: bool = False
    """Forward the event log on a connection of its own to the same broker (client id
    `<client_id>-events`, no last will; made again after each loss). Events stay QoS 1,
    marked delivered once acknowledged. Set it on a NATS cluster with `publish_qos: 0`: an
    event the cluster can't store yet after a node's death makes the node close the
    connection it came on, and apart it takes only itself, not the drives' states."""
    report: GatewayReportConfig = GatewayReportConfig()
    """Every drive's report by exception unless its own `report` says otherwise; `devices`:
    every device's, unless its device file says otherwise."""
    command_max_age_s: float = Field(10.0, gt=0)
    """A command whose `time` is older than this is refused (it sat in a queue somewhere), and
    so is one that waited longer than this in the gateway before its turn came."""
    commands_enabled: bool = True
    """False: monitoring only, every command on MQTT is refused (`set`, `write_parameter`);
    reads (`get`, `read_parameter`) are still answered."""
    queue_size: int = Field(1000, ge=1)
    """Events (faults, offline...) waiting for the broker; past this the oldest are dropped."""
    reconnect_max_s: float = Field(30.0, gt=0, le=3600)
    """Longest wait between two attempts to reach the broker (the wait doubles up to it)."""
    sparkplug: SparkplugConfig | None = None
    """The drives as Sparkplug B devices too (`spBv1.0/<group_id>/...`)."""

    @field_validator("base_topic", "discovery_prefix")
    @classmethod
    def _topic(cls, value: str) -> str:
        # Topics must travel between brokers unchanged: '+' and '#' are wildcards, an empty
        # level (a leading, trailing or double '/') is a different topic on some brokers, and
        # RabbitMQ's MQTT plugin turns '.' into '/', so commands on "site.a/pump1/set" would
        # silently never arrive.
        if not value:
            raise ValueError("must not be empty")
        for character, why in (("+", "a wildcard"), ("#", "a wildcard"), (".", _DOT)):
            if character in value:
                raise ValueError(f"no {character!r} in a topic: {why}")
        if "" in value.split("/"):
            raise ValueError("no empty level: no leading, trailing or double '/'")
        return value

    @field_validator("ca_file", "cert_file", "key_file")
    @classmethod
    def _readable(cls, value: str | None) -> str | None:
        # Found now rather than at the first connection attempt, retried in the background.
        return readable_file(value)

    @field_validator("servers")
    @classmethod
    def _servers(cls, value: tuple[str, ...] | None) -> tuple[str, ...] | None:
        if value is not None:
            if not value:
                raise ValueError("at least one host:port (or leave it out for host/port)")
            for server in value:
                broker_address(server)
            if len(set(value)) != len(value):
                raise ValueError("a server listed twice")
        return value

    @model_validator(mode="after")
    def _one_form(self) -> MqttConfig:
        given = sorted({"host", "port"} & self.model_fields_set)
        if self.servers is not None and given:
            keys = "/".join(given)
            raise ValueError(f"servers and {keys} both given: list every broker in servers alone")
        return self

    def broker_addresses(self) -> tuple[tuple[str, int], ...]:
        """The brokers to try, in order: `servers`, or the one `host`/`port`."""
        if self.servers is None:
            return ((self.host, self.port),)
        return tuple(broker_address(server) for server in self.servers)

    @model_validator(mode="after")
    def _tls_files(self) -> MqttConfig:
        files = [k for k in ("ca_file", "cert_file", "key_file") if getattr(self, k) is not None]
        if files and not self.tls:
            raise ValueError(f"{', '.join(files)} given but tls is false: set tls: true")
        if self.key_file is not None and self.cert_file is None:
            raise ValueError("key_file without cert_file: give the client certificate too")
        return self
