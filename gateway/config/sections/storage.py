"""`storage`: the local store's file, its size and how long events and history are kept."""

from __future__ import annotations

import os
from pathlib import Path

from pydantic import Field, model_validator

from gateway.config.sections.section import Section

DEFAULT_STATE_DIRECTORY = "/var/lib/invt-gateway"
ENV_STATE_DIRECTORY = "STATE_DIRECTORY"
"""Set by systemd's `StateDirectory=`: where the store goes when `storage.path` is left out."""


class StorageConfig(Section):
    """The local store: events waiting for the broker, and each drive's fault history."""

    path: str | None = Field(None, min_length=1)
    """The SQLite file; default `events-<gateway_id>.db` in $STATE_DIRECTORY (systemd's
    StateDirectory=), else in /var/lib/invt-gateway/ (an install that has the shared
    `events.db` of earlier releases goes on with it: see the Operations page)."""
    max_mb: float = Field(64.0, ge=0.05, le=100000)
    """The most the store may take on disk; past it the oldest events go first (counted and
    logged when they had not reached the broker yet)."""
    max_age_days: float = Field(90.0, gt=0, le=36500)
    """Events and faults older than this are removed."""
    history_days: float = Field(7.0, ge=0, le=3650)
    """How long the history of polled values is kept (one point a `history_step_s` per drive,
    for the console's charts); 0: none kept. Within max_mb: past it the oldest history goes
    before any event."""
    history_step_s: float = Field(60.0, ge=1, le=3600)
    """One history point per drive this often: the mean of each value over the step (a text
    value, such as the state, as it was last)."""

    outage_buffer_mb: float | None = Field(None, ge=0, le=100000)
    """Running values polled while the broker is away, kept in the store until the connection
    that missed them is back (JSON history messages, Sparkplug historical DDATA): at most this
    much of max_mb (default: a quarter of it, 16 of the default 64), the oldest going first past
    it (counted, logged, the gap marked); 0: none kept."""
    outage_buffer_hours: float = Field(24.0, gt=0, le=8760)
    """Outage values older than this go (counted, logged, the gap marked)."""

    @model_validator(mode="after")
    def _outage_buffer_within_the_store(self) -> StorageConfig:
        if self.outage_buffer_mb is not None and self.outage_buffer_mb > self.max_mb:
            raise ValueError(
                f"outage_buffer_mb ({self.outage_buffer_mb:g}) is part of max_mb "
                f"({self.max_mb:g}): it can't be more"
            )
        return self

    @property
    def outage_buffer(self) -> float:
        """`outage_buffer_mb`, or its default: a quarter of max_mb."""
        return self.max_mb / 4 if self.outage_buffer_mb is None else self.outage_buffer_mb

    def resolved_path(self, gateway_id: str, environ: dict[str, str] | None = None) -> str:
        """`path`, else `events-<gateway_id>.db` in the state directory: two gateways on one
        box (two lines, two `gateway_id`s) never share a store by default."""
        if self.path is not None:
            return self.path
        return str(state_directory(environ) / f"events-{gateway_id}.db")

    def shared_default(self, environ: dict[str, str] | None = None) -> str:
        """The default before it was one per gateway_id, `events.db` in the state directory:
        an install that has it goes on with it (the store's open decides)."""
        return str(state_directory(environ) / "events.db")


def state_directory(environ: dict[str, str] | None = None) -> Path:
    """Where the gateway keeps what it makes ($STATE_DIRECTORY, else /var/lib/invt-gateway)."""
    env = os.environ if environ is None else environ
    return Path(env.get(ENV_STATE_DIRECTORY, "").split(":")[0] or DEFAULT_STATE_DIRECTORY)
