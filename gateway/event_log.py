"""A log line for each fault a drive raises or clears, as the poller finds it.

Going offline and coming back are logged where they are detected (the bus and the poller); a
fault is only known from the poller's reads of 2102H, so this listener turns those events into
log lines: in the journal, "which drive tripped at 3 a.m., and with what" is one grep away.
"""

from __future__ import annotations

import logging

from gateway.poller.drive_state import DriveEvent, EventKind
from gateway.profile.telemetry import Telemetry

log = logging.getLogger(__name__)


class DriveEventLog:
    """A poll listener (`gateway.poller.PollListener`) that only logs faults."""

    def state_updated(self, drive: str, telemetry: Telemetry) -> None:
        pass

    def availability_changed(self, drive: str, online: bool) -> None:
        pass  # the poller logs it already

    def drive_event(self, event: DriveEvent) -> None:
        if event.kind is EventKind.FAULT_RAISED:
            log.warning("drive %s: fault raised: %s", event.drive, fault_words(event.data))
        elif event.kind is EventKind.FAULT_CLEARED:
            log.info("drive %s: fault cleared: %s", event.drive, fault_words(event.data))


def fault_words(data: Telemetry) -> str:
    """A fault in words: its profile's description (which holds its name) and its code; the
    OPC UA events' message says it so too."""
    return f"{data.get('fault_description')} (code {data.get('fault_code')})"
