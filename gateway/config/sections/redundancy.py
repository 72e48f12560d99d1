"""`redundancy`: two gateway boxes wired to one RS-485 line, one active and one standby (issue
48). Off by default: a gateway alone on its line is the active one, as it always was.

The coordinator that says which box is active is Keepalived (VRRP: one virtual address for
SCADA, a notify script on each role change, `config/keepalived.conf` and
`config/invt-gateway-notify.sh`); the gateway itself makes sure there is never a second master
on the line: it listens before it transmits, and an active that hears another master's frames
leaves the line (see the Redundancy page)."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from gateway.config.sections.section import Section


class RedundancyConfig(Section):
    """An active and a standby gateway on one line: never two masters."""

    enabled: bool = False
    """Share the lines with a second gateway box, one of the two active at a time."""
    role: Literal["standby", "active"] = "standby"
    """The role asked at start: `standby` (listens to the line, never transmits) until the
    coordinator asks `invt-gateway role active`; `active` takes the line at start, once it has
    heard the line silent (another master's frames keep it off)."""
    box: str = Field("", pattern=r"^[A-Za-z0-9_-]*$")
    """This box's name, where the two boxes differ: its retained role topic
    (`<base_topic>/bridge/redundancy/<box>`) and its MQTT client id's ending; default the host
    name (characters other than letters, digits, - and _ made -)."""
    peer: str = ""
    """How the other box is known, for the log, /health and the console (e.g. `gw-b
    10.0.0.12`); nothing is sent to it."""
    silence_ms: float | None = Field(None, ge=100, le=600000)
    """How long the line must be silent before this gateway transmits: a live active polls all
    the time, so silence this long means there is none. Default: from the poll cycle, three
    times the shortest poll interval of the drives polled, plus a response timeout with its
    retries, at least 1 s."""
    hold_off_ms: float = Field(0.0, ge=0, le=60000)
    """Silence waited beyond `silence_ms` by this box only: give the two boxes different
    values (0 and 500) so that, asked to take over at the same moment on a silent line (a cut
    link between them), one is heard first and the other stays off."""
    fault_file: str = ""
    """A file this gateway keeps at `0` while the box can be the line's master and sets to `1`
    the moment it can't (no port open on any line for a second: its adapter unplugged; the
    gateway stopping), for Keepalived's `track_file` (`weight 0`: FAULT at once, and the other
    box MASTER within a fraction of `advert_int`, not after the track script's failures).
    `/var/lib/invt-gateway/fault` under systemd (its store's directory, which outlives a
    restart); "": none written."""
    notify: Literal["keepalived", "manual"] = "keepalived"
    """Who asks for role changes on the control socket: `keepalived` (its notify script,
    `config/invt-gateway-notify.sh`) or `manual` (an operator's `invt-gateway role ...`)."""
