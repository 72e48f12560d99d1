"""The Modbus-TCP server's settings: its listeners (plain and TLS), limits and access rules."""

from __future__ import annotations

import ssl
from collections.abc import Mapping
from dataclasses import dataclass, field

from gateway.tcp.access import AccessRule


@dataclass(frozen=True, slots=True)
class TcpSettings:
    host: str = "0.0.0.0"
    port: int = 5020
    max_connections: int = 64
    idle_timeout_s: float = 300.0
    max_requests_per_connection: int = 16
    broadcast_reply: bool = True
    allowed_networks: tuple[str, ...] = ()
    read_only: bool = False
    access: tuple[AccessRule, ...] = ()
    """First match wins; none: every request may pass (see `gateway.tcp.access`)."""
    plain: bool = True
    """The plain listener (`host`, `port`); false: TLS only."""
    tls: TlsListener | None = None
    """The Modbus/TCP Security listener, if enabled."""
    first_request_timeout_s: float = 10.0
    max_connections_per_client: int | None = None
    """Slots one client address may hold; None: half of `max_connections` (at least 1)."""
    max_queued_writes_per_client: int = 16

    @property
    def per_client_limit(self) -> int:
        if self.max_connections_per_client is not None:
            return self.max_connections_per_client
        return max(1, self.max_connections // 2)


@dataclass(frozen=True, slots=True)
class TlsListener:
    host: str
    port: int
    cert_file: str
    key_file: str
    ca_file: str
    role_map: Mapping[str, str] = field(default_factory=dict)

    def context(self) -> ssl.SSLContext:
        """TLS 1.2 or later, and a client certificate the CA signed, or no connection."""
        context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
        context.minimum_version = ssl.TLSVersion.TLSv1_2
        context.verify_mode = ssl.CERT_REQUIRED
        context.load_cert_chain(self.cert_file, self.key_file)
        context.load_verify_locations(self.ca_file)
        return context
