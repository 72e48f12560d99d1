"""The models of the file's sections, one class per section (and per item of a list), each
validating its own keys: ranges, formats, files that must be readable, an unknown key refused.

What involves several sections (a drive's bus defined, unit ids unique) is in `cross_checks`;
the whole file's model is `schema.GatewayConfig`.
"""

from __future__ import annotations

import ipaddress
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Literal

from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    PlainValidator,
    field_validator,
    model_validator,
)

if TYPE_CHECKING:
    from gateway.profile import DriveProfile

ENV_MQTT_USERNAME = "INVT_GATEWAY_MQTT_USERNAME"
ENV_MQTT_PASSWORD = "INVT_GATEWAY_MQTT_PASSWORD"
STANDARD_BAUDRATES = (1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200)
CONFIG_VERSIONS = (1,)
"""The file format versions this gateway reads (`version:` in the file; without it, 1)."""


def readable_file(value: str | None) -> str | None:
    """A file the configuration names must be there and readable: said at load, with the key."""
    if value is not None and not os.access(value, os.R_OK):
        reason = "no such file" if not os.path.exists(value) else "not readable"
        raise ValueError(f"{value}: {reason}")
    return value


class Section(BaseModel):
    # An unknown key is almost always a typo that would silently do nothing: refuse it.
    # The docstring under each field is its description (`Field.description`): the
    # configuration reference (docs/) is generated from it, so it is what a user reads.
    model_config = ConfigDict(extra="forbid", frozen=True, use_attribute_docstrings=True)


@dataclass(frozen=True, slots=True)
class RegisterRange:
    """One entry of an access rule's `registers`: "2000H-2001H", "P00.00-P00.15", "2100H", 8192."""

    first: int
    last: int
    parameters: bool
    """Spelled as parameters (Pxx.yy): the range also covers their RAM-only addresses (8xxxH),
    which write the same parameters without the EEPROM."""

    @property
    def spans(self) -> tuple[tuple[int, int], ...]:
        if not self.parameters:
            return ((self.first, self.last),)
        from gateway.profile.addressing import RAM_BIT

        return (self.first, self.last), (self.first | RAM_BIT, self.last | RAM_BIT)


def _register_range(value: object) -> RegisterRange:
    from gateway.profile.addressing import is_parameter_register, parse_register

    if isinstance(value, RegisterRange):
        return value
    if isinstance(value, bool) or not isinstance(value, int | str):
        raise ValueError(f"{value!r}: write a register or a range, e.g. 2000H-2001H")
    if isinstance(value, int):
        if not 0 <= value <= 0xFFFF:
            raise ValueError(f"register {value} is outside 0..65535 (0000H..FFFFH)")
        return RegisterRange(value, value, False)
    ends = [end.strip() for end in value.split("-")]
    if len(ends) > 2 or not all(ends):
        raise ValueError(f"{value!r}: write one register or FIRST-LAST, e.g. 2000H-2001H")
    try:
        first, last = parse_register(ends[0]), parse_register(ends[-1])
    except ValueError as exc:
        raise ValueError(f"{value!r}: {exc}") from None
    if first > last:
        raise ValueError(f"{value!r}: the first register comes after the last")
    parameters = all(_PARAMETER_NAME.fullmatch(end) for end in ends)
    if parameters and not all(map(is_parameter_register, (first, last))):
        raise ValueError(f"{value!r} is not a parameter range")
    return RegisterRange(first, last, parameters)


_PARAMETER_NAME = re.compile(r"P\d{1,2}\.\d{1,2}", re.IGNORECASE)


def _function_code(value: object) -> object:
    """16, "10H" or "0x10" (function codes are usually written in hex)."""
    if isinstance(value, str):
        text = value.strip()
        try:
            if text[-1:] in "hH" and text[:-1]:
                return int(text[:-1], 16)
            if text.lower().startswith("0x"):
                return int(text, 16)
        except ValueError:
            pass
    return value


def _word(value: object) -> object:
    """0x01F0, "01F0H" or "0x01F0" (identification codes are written in hex)."""
    if isinstance(value, str):
        text = value.strip()
        try:
            if text[-1:] in "hH" and text[:-1]:
                return int(text[:-1], 16)
            return int(text, 0)
        except ValueError:
            pass
    return value


UnitId = Annotated[int, Field(ge=0, le=255)]
Word = Annotated[int, BeforeValidator(_word), Field(ge=0, le=0xFFFF)]
FunctionCode = Annotated[int, BeforeValidator(_function_code), Field(ge=1, le=127)]
Registers = Annotated[RegisterRange, PlainValidator(_register_range)]


class AccessRuleConfig(Section):
    """One rule of `modbus_tcp.access`: the first rule that matches a request decides."""

    name: str | None = Field(None, min_length=1, pattern=r"^[A-Za-z0-9_.-]+$")
    """Shown in logs and metrics (`rule` label); default `access[INDEX]`."""
    unit_ids: tuple[UnitId, ...] | None = None
    """The rule applies to these unit ids (0: broadcast); left out: to every unit id."""
    functions: tuple[FunctionCode, ...] | None = None
    """... to these function codes (3, "10H", "0x10"); left out: to every function code."""
    registers: tuple[Registers, ...] | None = None
    """... to requests for these registers (03H 04H 06H 10H 16H 17H): an allowing rule when every
    register of the request is inside, a refusing rule when any one is. Left out: any request."""
    allow: bool
    """True lets a matching request through, false refuses it (01H, or 02H for its registers)."""
    roles: tuple[str, ...] | None = None
    """... to clients of the TLS listener whose certificate carries one of these roles
    (`viewer`, `operator` or a site's own); left out: to every client."""

    @field_validator("unit_ids", "functions", "registers", "roles")
    @classmethod
    def _not_empty(cls, value: tuple[object, ...] | None) -> tuple[object, ...] | None:
        if value is not None and not value:
            raise ValueError("an empty list matches nothing: leave the key out to match all")
        return value


class ModbusTlsConfig(Section):
    """Modbus/TCP Security (the Modbus Organization's TLS profile): a second listener where
    clients prove who they are with a certificate, and their role limits what they may do."""

    enabled: bool = False
    """Start the TLS listener (it needs `cert_file`, `key_file` and `ca_file`)."""
    host: str | None = None
    """Bind address; default `modbus_tcp.host`."""
    port: int = Field(802, ge=0, le=65535)
    """802 is the profile's port (needs root or CAP_NET_BIND_SERVICE); 0 picks a free one."""
    cert_file: str | None = None
    """The gateway's certificate (PEM)."""
    key_file: str | None = None
    """The key of `cert_file` (PEM)."""
    ca_file: str | None = None
    """The CA that signs client certificates: only clients it vouches for get a connection."""
    role_map: dict[str, str] = {}
    """Role by the client certificate's common name, for certificates without the role
    extension (OID 1.3.6.1.4.1.50316.802.1)."""

    @model_validator(mode="after")
    def _files(self) -> ModbusTlsConfig:
        if self.enabled:
            missing = [k for k in ("cert_file", "key_file", "ca_file") if getattr(self, k) is None]
            if missing:
                raise ValueError(f"TLS needs {', '.join(missing)}")
        return self


class ModbusTcpConfig(Section):
    host: str = "0.0.0.0"
    """Bind address (`0.0.0.0`: every interface)."""
    port: int = Field(5020, ge=0, le=65535)
    """502 is Modbus's port (needs root or CAP_NET_BIND_SERVICE); 0 picks a free one."""
    max_connections: int = Field(64, ge=1, le=10000)
    """Two SCADA hosts, each with one connection per drive of a full 32-drive line."""
    idle_timeout_s: float = Field(300.0, gt=0)
    """A client silent this long is disconnected."""
    max_requests_per_connection: int = Field(16, ge=1, le=1024)
    """Outstanding (pipelined) requests one connection may have; more wait in its socket."""
    max_connections_per_client: int | None = Field(None, ge=1, le=10000)
    """Connections one client address may hold; default half of max_connections (32: a SCADA
    host with one connection per drive of a full line, or HMIs behind one NAT, fit; one host
    can't take every slot)."""
    first_request_timeout_s: float = Field(10.0, gt=0, le=3600)
    """A new connection must complete a request within this; otherwise it is closed."""
    max_queued_writes_per_client: int = Field(16, ge=1, le=1024)
    """Writes one connection may have waiting for the line; beyond, exception 0AH."""
    broadcast_reply: bool = True
    """Answer a broadcast (unit id 0) write with an echo, as if a drive had answered."""
    allowed_networks: tuple[str, ...] = ()
    """Client networks (CIDR) allowed to connect; empty allows every client."""
    plain: bool = True
    """The plain (unencrypted) listener; false leaves only the TLS one."""
    tls: ModbusTlsConfig = ModbusTlsConfig()
    """Modbus/TCP Security, a second listener for clients with certificates (see Security)."""
    read_only: bool = False
    """Refuse every write function code with exception 01H."""
    access: tuple[AccessRuleConfig, ...] = ()
    """Rules by unit id, function code and register; the first that matches decides, a request
    no rule matches is allowed. End with `{allow: false}` to refuse everything not listed."""

    @field_validator("allowed_networks")
    @classmethod
    def _networks(cls, value: tuple[str, ...]) -> tuple[str, ...]:
        for network in value:
            try:
                ipaddress.ip_network(network, strict=False)
            except ValueError as exc:
                raise ValueError(f"{network!r} is not a network in CIDR form: {exc}") from exc
        return value

    @model_validator(mode="after")
    def _a_listener(self) -> ModbusTcpConfig:
        if not self.plain and not self.tls.enabled:
            raise ValueError("plain: false needs tls.enabled: true, or no client could connect")
        return self


class Rs485Config(Section):
    """Who switches the RS-485 transceiver's driver on around each request (`buses[].rs485`).

    Leave it out for USB adapters, which do it themselves. A UART with a transceiver on it
    (a Raspberry Pi hat, an industrial box's ttyS port) needs one of the two modes."""

    mode: Literal["kernel", "rts"]
    """`kernel`: the serial driver's RS-485 mode (TIOCSRS485) switches RTS; `rts`: the gateway
    toggles RTS around each write and releases it once the UART has drained."""
    rts_level_for_tx: Literal["high", "low"] = "high"
    """RTS level while transmitting (low where the board inverts DE)."""
    delay_before_tx_ms: float = Field(0.0, ge=0, le=1000)
    """From driver enabled to the first bit (kernel mode: whole milliseconds)."""
    delay_after_tx_ms: float = Field(0.0, ge=0, le=1000)
    """From the last bit sent to driver released; must stay below the drives' response delay
    (P14.03) or their replies meet a line still driven (kernel mode: whole milliseconds)."""


class BusConfig(Section):
    name: str = Field(min_length=1, pattern=r"^[A-Za-z0-9_.-]+$")
    """The line's name, which each drive's `bus` names."""
    port: str = Field(min_length=1)
    """A device path (prefer /dev/serial/by-id/...) or a pyserial URL (socket://host:port)."""
    baudrate: int = Field(19200, json_schema_extra={"unit": "bit/s"})
    """One of 1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200: the drives' own (INVT
    P14.01)."""
    parity: Literal["N", "E", "O"] = "E"
    """`N`, `E` or `O`, as the drives' (INVT P14.02, default E81: even parity, 8 data bits, 1
    stop bit)."""
    stopbits: Literal[1, 2] = 1
    """Stop bits, as the drives' (INVT P14.02)."""
    bytesize: Literal[7, 8] = 8
    """Data bits, as the drives' (INVT P14.02)."""
    timeout_ms: float = Field(300.0, gt=0, le=60000)
    """Response timeout per attempt: end of request to first byte of the reply."""
    retries: int = Field(2, ge=0, le=10)
    """Further attempts after a timeout or a bad reply (never after an exception reply)."""
    char_timeout_ms: float = Field(20.0, gt=0, le=5000)
    """Silence inside a reply that ends it (USB adapters deliver bytes in bursts)."""
    drain_ms: float = Field(50.0, ge=0, le=60000)
    """After a timeout, how long to listen for a late reply before the next request."""
    gap_ms: float | None = Field(None, gt=0, le=10000)
    """Inter-frame silence; default t3.5 (3.5 characters, 1.75 ms above 19200 baud)."""
    turnaround_ms: float = Field(100.0, ge=0, le=10000)
    """Silence after a broadcast, while every drive acts on it."""
    queue_size: int = Field(256, ge=1, le=100000)
    """Requests waiting for the line; beyond it a SCADA request is answered exception 0AH (and
    counted)."""
    offline_after: int = Field(3, ge=1, le=1000)
    """Consecutive failed requests after which a drive is offline (answered 0x0B at once)."""
    probe_max_s: float = Field(30.0, gt=0, le=3600)
    """Longest wait between two probes of an offline drive."""
    echo: bool = False
    """The adapter echoes what it sends (no echo suppression): read it back and check it."""
    rs485: Rs485Config | None = None
    """RS-485 direction control for UARTs with a transceiver; None for adapters that do it."""
    write_share: float = Field(0.5, gt=0, le=1)
    """While reads wait, the most of the line's time writes may take (writes still go first)."""
    broadcast_share: float = Field(0.1, gt=0, le=1)
    """While other requests wait, the most of the line's time broadcasts (and their turnaround)
    may take."""
    poll_share: float = Field(0.05, gt=0, le=1)
    """While client reads wait, the most of the line's time the poller's reads may take (with
    no client read waiting they take all of it): every second a full line gives the polls is
    one the clients wait longer. Raise it for fresher telemetry under a SCADA that keeps the
    line busy."""

    @field_validator("baudrate")
    @classmethod
    def _baudrate(cls, value: int) -> int:
        if value not in STANDARD_BAUDRATES:
            raise ValueError(f"must be one of {', '.join(map(str, STANDARD_BAUDRATES))}")
        return value


class PollGroupConfig(Section):
    name: str = Field(min_length=1)
    """The group's name (in logs and metrics)."""
    start: int = Field(ge=0, le=0xFFFF)
    """The first register read (`0x2100`)."""
    count: int = Field(ge=1, le=125)
    """How many registers from `start` one read takes."""
    interval_ms: float = Field(gt=0)
    """How often the group is read."""


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


class MetricsConfig(Section):
    enabled: bool = False
    """Serve `/metrics` (Prometheus) and `/health`."""
    host: str = "127.0.0.1"
    """Bind address; loopback by default."""
    port: int = Field(9102, ge=1, le=65535)
    """`/metrics` and `/health` on the same port."""


DEFAULT_STATE_DIRECTORY = "/var/lib/invt-gateway"
ENV_STATE_DIRECTORY = "STATE_DIRECTORY"
"""Set by systemd's `StateDirectory=`: where the store goes when `storage.path` is left out."""


class StorageConfig(Section):
    """The local store: events waiting for the broker, and each drive's fault history."""

    path: str | None = Field(None, min_length=1)
    """The SQLite file; default `events-<gateway_id>.db` in $STATE_DIRECTORY (systemd's
    StateDirectory=), else in /var/lib/invt-gateway/ (an install that has the shared
    `events.db` of earlier releases goes on with it: see the Operations page)."""
    max_mb: float = Field(64.0, ge=0.05, le=100000)
    """The most the store may take on disk; past it the oldest events go first (counted and
    logged when they had not reached the broker yet)."""
    max_age_days: float = Field(90.0, gt=0, le=36500)
    """Events and faults older than this are removed."""
    history_days: float = Field(7.0, ge=0, le=3650)
    """How long the history of polled values is kept (one point a `history_step_s` per drive,
    for the console's charts); 0: none kept. Within max_mb: past it the oldest history goes
    before any event."""
    history_step_s: float = Field(60.0, ge=1, le=3600)
    """One history point per drive this often: the mean of each value over the step (a text
    value, such as the state, as it was last)."""

    def resolved_path(self, gateway_id: str, environ: dict[str, str] | None = None) -> str:
        """`path`, else `events-<gateway_id>.db` in the state directory: two gateways on one
        box (two lines, two `gateway_id`s) never share a store by default."""
        if self.path is not None:
            return self.path
        return str(_state_directory(environ) / f"events-{gateway_id}.db")

    def shared_default(self, environ: dict[str, str] | None = None) -> str:
        """The default before it was one per gateway_id, `events.db` in the state directory:
        an install that has it goes on with it (the store's open decides)."""
        return str(_state_directory(environ) / "events.db")


def _state_directory(environ: dict[str, str] | None) -> Path:
    env = os.environ if environ is None else environ
    return Path(env.get(ENV_STATE_DIRECTORY, "").split(":")[0] or DEFAULT_STATE_DIRECTORY)


class ConsoleUserConfig(Section):
    name: str = Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.@-]+$")
    """The login name."""
    password_hash: str
    """`invt-gateway hash-password` makes it (salted scrypt); never the password itself."""
    role: Literal["viewer", "operator", "admin"] = "viewer"
    """viewer: sees everything; operator: also commands and writes (when commands_enabled);
    admin: what an operator may, and edits the configuration from the console."""
    token_hash: str | None = None
    """The user's API token, hashed (`invt-gateway hash-password --new-token` makes one):
    scripts and `invt-gateway monitor` send the token as `Authorization: Bearer TOKEN`."""

    @field_validator("password_hash")
    @classmethod
    def _a_password_hash(cls, value: str) -> str:
        from gateway.passwords import check_password_hash

        check_password_hash(value)  # a password pasted here instead of its hash is refused
        return value

    @field_validator("token_hash")
    @classmethod
    def _a_token_hash(cls, value: str | None) -> str | None:
        from gateway.passwords import check_token_hash

        if value is not None:
            check_token_hash(value)
        return value


class ConsoleConfig(Section):
    enabled: bool = False
    """Start the console (it needs `users`, or `anonymous_view: true`)."""
    host: str = "127.0.0.1"
    """Loopback by default: a console on the plant network is a decision, not an accident."""
    port: int = Field(8080, ge=0, le=65535)
    """0 picks a free one."""
    users: tuple[ConsoleUserConfig, ...] = ()
    """Who may log in, each with a role."""
    commands_enabled: bool = True
    """False: the console only shows; every command and write from it is refused."""
    anonymous_view: bool = False
    """True: pages and the read API without a login (as a viewer); writes always need one."""
    cert_file: str | None = None
    """With `key_file`: HTTPS only, and the session cookie Secure."""
    key_file: str | None = None
    """Both given: the console speaks HTTPS only."""
    request_timeout_s: float = Field(10.0, gt=0, le=3600)
    """A request's head must arrive within this of connecting (or of its first byte), its body
    within this of its head; otherwise the connection is closed (and counted)."""

    @field_validator("cert_file", "key_file")
    @classmethod
    def _readable(cls, value: str | None) -> str | None:
        return readable_file(value)

    @model_validator(mode="after")
    def _checks(self) -> ConsoleConfig:
        if (self.cert_file is None) != (self.key_file is None):
            raise ValueError("cert_file and key_file go together: give both for HTTPS, or neither")
        names = [user.name for user in self.users]
        duplicates = sorted({name for name in names if names.count(name) > 1})
        if duplicates:
            raise ValueError(f"users: duplicate name {', '.join(duplicates)}")
        if self.enabled and not self.users and not self.anonymous_view:
            raise ValueError("enabled with no users and anonymous_view false: nobody could use it")
        return self


class LoggingConfig(Section):
    level: Literal["debug", "info", "warning", "error"] = "info"
    """`debug` also hex-dumps every frame on the wire."""
    format: Literal["text", "json"] = "text"
    """`text`, or `json` (one object a line, for journald or Loki)."""
