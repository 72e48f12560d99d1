"""Modbus-TCP's front door: listeners, limits and access rules."""

from __future__ import annotations

from gateway.config import AccessRuleConfig, ModbusTcpConfig
from gateway.tcp import TcpSettings
from gateway.tcp.access import AccessRule, merge_spans
from gateway.tcp.server import TlsListener


def access_rule(config: AccessRuleConfig, index: int) -> AccessRule:
    spans = None
    if config.registers is not None:
        spans = merge_spans(span for entry in config.registers for span in entry.spans)
    return AccessRule(
        allow=config.allow,
        unit_ids=None if config.unit_ids is None else frozenset(config.unit_ids),
        functions=None if config.functions is None else frozenset(config.functions),
        spans=spans,
        label=config.name or f"access[{index}]",
        roles=None if config.roles is None else frozenset(config.roles),
    )


def tls_listener(config: ModbusTcpConfig) -> TlsListener | None:
    tls = config.tls
    if not tls.enabled:
        return None
    # The config refuses tls.enabled without the three files.
    return TlsListener(
        host=tls.host or config.host,
        port=tls.port,
        cert_file=tls.cert_file or "",
        key_file=tls.key_file or "",
        ca_file=tls.ca_file or "",
        role_map=dict(tls.role_map),
    )


def tcp_settings(tcp: ModbusTcpConfig) -> TcpSettings:
    return TcpSettings(
        host=tcp.host,
        port=tcp.port,
        max_connections=tcp.max_connections,
        idle_timeout_s=tcp.idle_timeout_s,
        max_requests_per_connection=tcp.max_requests_per_connection,
        broadcast_reply=tcp.broadcast_reply,
        allowed_networks=tcp.allowed_networks,
        read_only=tcp.read_only,
        access=tuple(access_rule(r, i) for i, r in enumerate(tcp.access)),
        first_request_timeout_s=tcp.first_request_timeout_s,
        plain=tcp.plain,
        tls=tls_listener(tcp),
        max_connections_per_client=tcp.max_connections_per_client,
        max_queued_writes_per_client=tcp.max_queued_writes_per_client,
    )
