"""`console`: the operator's web console, its listener and its users."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator, model_validator

from gateway.config.sections.section import Section, readable_file


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
