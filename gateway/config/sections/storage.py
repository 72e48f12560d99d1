"""`storage`: the local store's file, its size and how long events and history are kept."""

from __future__ import annotations

import os
from pathlib import Path

from pydantic import Field

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
