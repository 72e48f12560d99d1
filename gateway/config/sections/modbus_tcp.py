"""`modbus_tcp`: the Modbus-TCP server SCADA connects to, its TLS listener and its access rules."""

from __future__ import annotations

import ipaddress

from pydantic import Field, field_validator, model_validator

from gateway.config.sections.section import Section
from gateway.config.sections.values import FunctionCode, Registers, UnitId


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
