"""The bridge's counters: plain numbers, each written by the one part that does the counting."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from gateway.poller.drive_state import iso_time


@dataclass(slots=True)
class BridgeStats:
    connects: int = 0
    connect_failures: int = 0
    published: int = 0
    commands_received: int = 0
    ignored: int = 0
    conflicts: int = 0
    busy: int = 0
    """Messages refused because their lane was full."""
    tls_failures: int = 0
    """Attempts to build the TLS context from the configured files that failed."""


@dataclass(frozen=True, slots=True)
class SessionStatus:
    """The broker connection as a diagnostics page shows it (`MqttBridge.status`)."""

    broker: str
    """host:port"""
    tls: bool
    protocol: str
    """"5" or "3.1.1": the one tried now, the broker's once connected."""
    connected: bool
    connected_since: float | None
    queued: int
    """Events recorded and not yet acknowledged by the broker."""
    dropped: int
    """Events dropped before the broker had them (the store's bounds)."""
    last_error: str | None
    last_error_at: float | None
    connects: int
    connect_failures: int
    published: int

    def to_json(self) -> dict[str, Any]:
        return {
            "broker": self.broker,
            "tls": self.tls,
            "protocol": self.protocol,
            "connected": self.connected,
            "connected_since": _time(self.connected_since),
            "queued": self.queued,
            "dropped": self.dropped,
            "last_error": self.last_error,
            "last_error_at": _time(self.last_error_at),
            "connects": self.connects,
            "connect_failures": self.connect_failures,
            "published": self.published,
        }


def _time(epoch_s: float | None) -> str | None:
    return None if epoch_s is None else iso_time(epoch_s)
