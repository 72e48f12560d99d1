"""`opcua`: the OPC UA server SCADA, MES and historians connect to (see OPC UA).

Who may log in is the console's `users` (their roles: a viewer browses, reads and subscribes; an
operator and an admin also write and call methods); the section itself says where the server
listens, which security it offers and where its certificates are.
"""

from __future__ import annotations

import re
from typing import Literal

from pydantic import Field, field_validator, model_validator

from gateway.config.sections.section import Section, readable_file

PARAMETER_OR_GROUP = re.compile(r"[Pp]\d\d(\.\d\d)?")
SecurityChoice = Literal[
    "None",
    "Basic256Sha256_Sign",
    "Basic256Sha256_SignAndEncrypt",
    "Aes128_Sha256_RsaOaep_Sign",
    "Aes128_Sha256_RsaOaep_SignAndEncrypt",
    "Aes256_Sha256_RsaPss_Sign",
    "Aes256_Sha256_RsaPss_SignAndEncrypt",
]
"""Each a policy (OPC UA's name for it) and a mode; the Aes policies are OPC UA 1.04's, which
newer clients prefer (Basic256Sha256 is what every client has)."""


class OpcUaConfig(Section):
    enabled: bool = False
    """Start the OPC UA server (it needs `console.users`, or `anonymous: true`)."""
    host: str = "127.0.0.1"
    """Bind address; loopback by default, as the console's: `0.0.0.0` for the plant network."""
    port: int = Field(4840, ge=1, le=65535)
    """OPC UA's registered port by default."""
    security: tuple[SecurityChoice, ...] = (
        "Basic256Sha256_SignAndEncrypt",
        "Basic256Sha256_Sign",
    )
    """The endpoints offered, each a security policy and mode. `None` (no signing, no
    encryption: passwords then travel in clear) only when listed here, and a warning is logged
    at every start that offers it."""
    certificate_file: str | None = None
    """The server's application certificate (DER or PEM), with `private_key_file`; left out, one
    is made on the first start (RSA 2048, SHA-256, ten years) as `opcua/server-cert.der` in the
    state directory (see `storage.path`) and kept; its SHA-1 thumbprint is logged at each start,
    for a client's administrator to compare."""
    private_key_file: str | None = None
    """The certificate's private key (PEM); with `certificate_file`."""
    trusted_clients_dir: str | None = None
    """Client certificates trusted (DER or PEM, one a file); default `opcua/trusted` in the
    state directory. A client whose certificate is not here is refused (BadCertificateUntrusted)
    and its certificate kept in `rejected_clients_dir`: move the file here to trust it (read at
    each connection, no restart)."""
    rejected_clients_dir: str | None = None
    """Where refused client certificates are kept (`<thumbprint>.der`); default
    `opcua/rejected` in the state directory."""
    anonymous: bool = False
    """True: a client may connect without a login, as a viewer (browse, read, subscribe)."""
    commands_enabled: bool = True
    """False: writes and methods are refused to everyone (BadUserAccessDenied): monitoring only."""
    max_connections: int = Field(16, ge=1, le=1000)
    """Clients connected at once; one more is closed as it connects (and logged)."""
    max_subscriptions: int = Field(64, ge=1, le=10000)
    """Subscriptions across all sessions; one more is refused with BadTooManySubscriptions."""
    max_monitored_items: int = Field(2000, ge=1, le=100000)
    """Monitored items one session may have across its subscriptions (32 drives of 48 values
    each is 1,536); beyond it, BadTooManyMonitoredItems for each item asked."""
    parameters: Literal["all", "none"] | tuple[str, ...] = ("P00",)
    """Which parameters each INVT drive shows under `Parameters`: a list of groups and codes
    (`[P00, P01, P07.27]`; by default the basic functions, group P00), `all` (every row of its
    series' table, 425 for a GD20) or `none`. Each parameter costs the server about 17 KB of
    memory (its node and its EngineeringUnits and EURange): a GD20's all are about 7 MB and
    0.4 s at start, 32 drives' all some 240 MB: the default keeps a small box small."""
    parameter_max_age_s: float = Field(10.0, ge=0.5, le=3600.0)
    """A parameter node (`Parameters/P00.03`, not polled) read from the drive is answered from
    what was read for this long; a Read after it reads the drive again."""

    @field_validator("security")
    @classmethod
    def _some(cls, value: tuple[SecurityChoice, ...]) -> tuple[SecurityChoice, ...]:
        if not value:
            raise ValueError("no endpoint: list at least one security policy and mode")
        return value

    @field_validator("parameters")
    @classmethod
    def _parameters(cls, value: str | tuple[str, ...]) -> str | tuple[str, ...]:
        if isinstance(value, str):
            return value
        for text in value:
            if not PARAMETER_OR_GROUP.fullmatch(text):
                raise ValueError(f"{text!r} is not a group (P00) or a parameter (P00.03)")
        return tuple(text.upper() for text in value)

    @field_validator("certificate_file", "private_key_file")
    @classmethod
    def _readable(cls, value: str | None) -> str | None:
        return readable_file(value)

    @model_validator(mode="after")
    def _pair(self) -> OpcUaConfig:
        if (self.certificate_file is None) != (self.private_key_file is None):
            raise ValueError(
                "certificate_file and private_key_file go together: give both, or neither (one "
                "is then made in the state directory)"
            )
        return self
