"""`metrics` and `logging`: how the gateway tells about itself (/metrics and /health, the log)."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from gateway.config.sections.section import Section


class MetricsConfig(Section):
    enabled: bool = False
    """Serve `/metrics` (Prometheus) and `/health`."""
    host: str = "127.0.0.1"
    """Bind address; loopback by default."""
    port: int = Field(9102, ge=1, le=65535)
    """`/metrics` and `/health` on the same port."""


class LoggingConfig(Section):
    level: Literal["debug", "info", "warning", "error"] = "info"
    """`debug` also hex-dumps every frame on the wire."""
    format: Literal["text", "json"] = "text"
    """`text`, or `json` (one object a line, for journald or Loki)."""
