"""The OPC UA server's settings: its endpoint, the security it offers, its certificates, who
may log in (the console's users)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from gateway.config import GatewayConfig
from gateway.config.sections.storage import state_directory
from gateway.settings.local import ConsoleUser, console_user

OWN_FOLDER = "opcua"
"""The server's own files in the state directory: its certificate and key, the client
certificates trusted and refused."""


@dataclass(frozen=True, slots=True)
class OpcUaSettings:
    gateway_id: str
    host: str
    port: int
    security: tuple[str, ...]
    """`None`, `Basic256Sha256_Sign`, `Aes128_Sha256_RsaOaep_SignAndEncrypt`...: the endpoints
    offered (`config.sections.opcua.SecurityChoice`)."""
    certificate_file: Path
    private_key_file: Path
    make_certificate: bool
    """True: the files are the gateway's own, made on the first start when absent."""
    trusted_clients_dir: Path
    rejected_clients_dir: Path
    users: tuple[ConsoleUser, ...]
    anonymous: bool
    commands_enabled: bool
    max_connections: int = 16
    max_subscriptions: int = 64
    max_monitored_items: int = 2000
    parameters: str | tuple[str, ...] = "all"
    """`all`, `none`, or the groups (P00) and codes (P00.03) shown under `Parameters`."""
    parameter_max_age_s: float = 10.0
    command_max_age_s: float = 10.0
    """What `Commands` asks of every source: a method call is carried out at once, never late."""

    @property
    def endpoint(self) -> str:
        return f"opc.tcp://{self.host}:{self.port}/invt-gateway"

    @property
    def application_uri(self) -> str:
        """Unique per gateway: a client's trust list tells two gateways apart by it."""
        return f"urn:invt-gateway:{self.gateway_id}"


def opcua_settings(config: GatewayConfig) -> OpcUaSettings | None:
    """The server's settings; None when not enabled."""
    opcua = config.opcua
    if not opcua.enabled:
        return None
    own = state_directory() / OWN_FOLDER
    made = opcua.certificate_file is None or opcua.private_key_file is None
    return OpcUaSettings(
        gateway_id=config.gateway_id,
        host=opcua.host,
        port=opcua.port,
        security=opcua.security,
        certificate_file=own / "server-cert.der" if made else Path(str(opcua.certificate_file)),
        private_key_file=own / "server-key.pem" if made else Path(str(opcua.private_key_file)),
        make_certificate=made,
        trusted_clients_dir=_folder(opcua.trusted_clients_dir, own / "trusted"),
        rejected_clients_dir=_folder(opcua.rejected_clients_dir, own / "rejected"),
        users=tuple(console_user(user) for user in config.console.users),
        anonymous=opcua.anonymous,
        commands_enabled=opcua.commands_enabled,
        max_connections=opcua.max_connections,
        max_subscriptions=opcua.max_subscriptions,
        max_monitored_items=opcua.max_monitored_items,
        parameters=opcua.parameters,
        parameter_max_age_s=opcua.parameter_max_age_s,
    )


def _folder(given: str | None, default: Path) -> Path:
    return default if given is None else Path(given)
