"""The Modbus-TCP front door's counters: plain numbers the server and its TLS handshakes write,
and the metrics (`gateway.tcp.metrics`) and `/health` read at scrape time."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field


@dataclass(slots=True)
class TcpStats:
    connections: int = 0
    accepted: int = 0
    refused: int = 0
    malformed: int = 0
    idle_closed: int = 0
    requests: int = 0
    exceptions: int = 0
    denied: int = 0
    evicted: int = 0
    """Connections closed to make room: they had never completed a request."""
    slow_closed: int = 0
    """Connections closed for a frame not completed in time, or no request after connecting."""
    write_limited: int = 0
    """Writes refused with 0AH: the client had `max_queued_writes_per_client` waiting."""
    tls_handshake_timeouts: int = 0
    """TLS connections closed for a handshake not done within `first_request_timeout_s`."""
    tls_handshakes_failed: int = 0
    """TLS handshakes that failed: no certificate, one the CA didn't sign, a protocol error."""
    malformed_requests: Counter[str] = field(default_factory=Counter)
    """Requests answered at the front door (01H or 03H), by reason (`Reason` of the registry)."""
    active: set[str] = field(default_factory=set)
