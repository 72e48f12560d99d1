"""The bridge's counters: plain numbers, each written by the one part that does the counting."""

from __future__ import annotations

from dataclasses import dataclass


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
