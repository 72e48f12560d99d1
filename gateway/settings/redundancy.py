"""`redundancy:` as the running gateway uses it: the role asked at start, the peer, and the
silence that says no other master is on the line, worked out from the poll cycle when the file
leaves it out."""

from __future__ import annotations

import re
import socket
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

from gateway.bus import BusSettings
from gateway.config import GatewayConfig
from gateway.config.peer import shared_digests
from gateway.settings.lines import DriveSettings

LEAST_SILENCE_S = 1.0
"""The derived silence is never shorter: a busy machine's event loop, or a drive's slow answer,
may leave the line quiet for a few hundred milliseconds while its master lives."""
POLL_CYCLES = 3
"""Missed polls before the line counts as silent: one late poll is no dead master."""


@dataclass(frozen=True, slots=True)
class RedundancySettings:
    start_role: str
    """`standby` or `active`: the role asked at start."""
    box: str
    """This box's name (`redundancy.box`, or the host name made topic-safe)."""
    peer: str
    silence_s: float
    """Silence on the line before this gateway transmits."""
    hold_off_s: float
    """Silence waited beyond `silence_s` by this box only."""
    notify: str
    fault_file: str
    """Keepalived's track file this gateway keeps (`FaultFile`); "": none."""
    silence_derived: bool
    """`silence_s` was worked out from the poll cycle, not configured."""
    shared_digests: Mapping[str, str]
    """What this box runs of the configuration both boxes must share: a digest per key
    (`gateway.config.peer.shared_digests`), for the other box to compare (`PeerConfig`)."""

    @property
    def listen_s(self) -> float:
        """The whole silence this box hears before it takes the line."""
        return self.silence_s + self.hold_off_s


def redundancy_settings(
    whole: GatewayConfig,
    buses: Iterable[BusSettings],
    polled: Iterable[DriveSettings],
) -> RedundancySettings | None:
    """`whole.redundancy` as it runs; None when redundancy is off."""
    config = whole.redundancy
    if not config.enabled:
        return None
    silence_s = derived_silence_s(buses, polled) if config.silence_ms is None else None
    return RedundancySettings(
        start_role=config.role,
        box=config.box or re.sub(r"[^A-Za-z0-9_-]", "-", socket.gethostname()) or "box",
        peer=config.peer,
        silence_s=silence_s if silence_s is not None else (config.silence_ms or 0) / 1000,
        hold_off_s=config.hold_off_ms / 1000,
        notify=config.notify,
        fault_file=config.fault_file,
        silence_derived=config.silence_ms is None,
        shared_digests=shared_digests(whole),
    )


def derived_silence_s(buses: Iterable[BusSettings], polled: Iterable[DriveSettings]) -> float:
    """`POLL_CYCLES` times the shortest poll interval, plus the longest a request may go
    unanswered on any line (its response timeout, with its retries): the longest a live
    active leaves the line quiet while its drives answer, with margin. At least
    `LEAST_SILENCE_S`."""
    intervals = [g.interval_s for d in polled for g in d.poll_groups]
    shortest = min(intervals, default=LEAST_SILENCE_S)
    unanswered = max(
        ((b.timeout_s * (b.retries + 1)) for b in buses),
        default=0.0,
    )
    return max(POLL_CYCLES * shortest + unanswered, LEAST_SILENCE_S)
