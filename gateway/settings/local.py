"""The features on the gateway's own host: the store, metrics and health, the console."""

from __future__ import annotations

from dataclasses import dataclass

from gateway.config import ConsoleConfig, ConsoleUserConfig, GatewayConfig, MetricsConfig

EVENTS_WAITING = 1000
"""Events waiting in memory for the store's disk (without MQTT, whose queue_size says it)."""


@dataclass(frozen=True, slots=True)
class StoreSettings:
    path: str
    """The SQLite file, resolved (`storage.path`, else in systemd's StateDirectory)."""
    max_mb: float
    max_age_days: float
    forwarding: bool
    """Events wait for the broker too (MQTT enabled)."""
    max_waiting: int
    """Events waiting in memory for the disk."""
    history_days: float = 7.0
    """How long the history of polled values is kept; 0: none."""
    history_step_s: float = 60.0
    """One history point per drive this often."""
    outage_buffer_mb: float = 16.0
    """Running values polled while the broker is away, kept until delivered; 0: none."""
    outage_buffer_hours: float = 24.0
    shared_path: str | None = None
    """Without storage.path: the default store before it was one per gateway_id, kept in use
    by an install that has it (`gateway.store.database.EventDatabase._choose_file`)."""


def store_settings(config: GatewayConfig) -> StoreSettings:
    mqtt = config.mqtt
    storage = config.storage
    return StoreSettings(
        path=storage.resolved_path(config.gateway_id),
        max_mb=storage.max_mb,
        max_age_days=storage.max_age_days,
        forwarding=mqtt is not None and mqtt.enabled,
        max_waiting=mqtt.queue_size if mqtt is not None else EVENTS_WAITING,
        history_days=storage.history_days,
        history_step_s=storage.history_step_s,
        outage_buffer_mb=storage.outage_buffer if mqtt is not None and mqtt.enabled else 0.0,
        outage_buffer_hours=storage.outage_buffer_hours,
        shared_path=storage.shared_default() if storage.path is None else None,
    )


@dataclass(frozen=True, slots=True)
class MetricsSettings:
    host: str
    port: int


def metrics_settings(config: MetricsConfig) -> MetricsSettings | None:
    """Where /metrics and /health listen; None when not enabled."""
    return MetricsSettings(config.host, config.port) if config.enabled else None


@dataclass(frozen=True, slots=True)
class ConsoleUser:
    name: str
    password_hash: str
    role: str
    """"viewer", "operator" or "admin"."""
    token_hash: str | None


@dataclass(frozen=True, slots=True)
class ConsoleSettings:
    host: str
    port: int
    users: tuple[ConsoleUser, ...]
    commands_enabled: bool
    anonymous_view: bool
    cert_file: str | None
    key_file: str | None
    """Both given: HTTPS only (the config refuses one without the other)."""
    request_timeout_s: float = 10.0
    """A request's head, then its body, must arrive within this (`gateway.console.deadlines`)."""


def console_user(config: ConsoleUserConfig) -> ConsoleUser:
    return ConsoleUser(config.name, config.password_hash, config.role, config.token_hash)


def console_settings(config: ConsoleConfig) -> ConsoleSettings | None:
    """The console's settings; None when not enabled."""
    if not config.enabled:
        return None
    return ConsoleSettings(
        host=config.host,
        port=config.port,
        users=tuple(console_user(user) for user in config.users),
        commands_enabled=config.commands_enabled,
        anonymous_view=config.anonymous_view,
        cert_file=config.cert_file,
        key_file=config.key_file,
        request_timeout_s=config.request_timeout_s,
    )
