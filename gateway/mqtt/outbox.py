"""What the poller hands the MQTT bridge: bounded, never blocking the poller.

The poller must never wait for the broker (it may be down for hours), so handing over is a plain
call that returns at once. States and availabilities are kept per drive, the newest replacing the
older (only the newest matters, and there are as many as drives: bounded by nature). Events are
each worth telling, so they queue, up to `max_events`; past that the oldest is dropped and counted.

What the bridge took but could not publish (the connection broke halfway) it hands back with
`restore`: events go back in front, in their order, so a `fault_raised` is late rather than lost;
a state or availability goes back unless a newer one came meanwhile. Only an overflowing queue
drops an event.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections import deque
from dataclasses import dataclass, field

from gateway.poller import DriveEvent
from gateway.profile.telemetry import Telemetry

log = logging.getLogger(__name__)

DROP_LOG_EVERY = 1000
"""The first drop is logged, then one line per this many: a long outage must not flood the log."""


@dataclass(slots=True)
class OutboxStats:
    states: int = 0
    states_superseded: int = 0
    """States replaced by a newer one before the bridge took them (harmless)."""
    events: int = 0
    events_dropped: int = 0
    """Events lost because the queue was full (the broker was away too long)."""


@dataclass(slots=True)
class Pending:
    states: dict[str, Telemetry] = field(default_factory=dict)
    availability: dict[str, bool] = field(default_factory=dict)
    events: deque[DriveEvent] = field(default_factory=deque)

    def __bool__(self) -> bool:
        return bool(self.states or self.availability or self.events)


class Outbox:
    def __init__(self, max_events: int) -> None:
        self.stats = OutboxStats()
        self._states: dict[str, Telemetry] = {}
        self._availability: dict[str, bool] = {}
        self._events: deque[DriveEvent] = deque()
        self._max_events = max_events
        self._ready = asyncio.Event()

    def put_state(self, drive: str, telemetry: Telemetry) -> None:
        self.stats.states += 1
        if drive in self._states:
            self.stats.states_superseded += 1
        self._states[drive] = telemetry
        self._ready.set()

    def put_availability(self, drive: str, online: bool) -> None:
        self._availability[drive] = online
        self._ready.set()

    def put_event(self, event: DriveEvent) -> None:
        self.stats.events += 1
        self._events.append(event)
        self._drop_overflow()
        self._ready.set()

    async def wait(self, timeout_s: float) -> None:
        """Until something is pending, or `timeout_s` has passed."""
        if not self._ready.is_set():
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(timeout_s):
                    await self._ready.wait()

    def take(self) -> Pending:
        pending = Pending(self._states, self._availability, self._events)
        self._states, self._availability, self._events = {}, {}, deque()
        self._ready.clear()
        return pending

    def restore(self, unsent: Pending) -> None:
        """Hand back what was taken but not published: it goes out first next time."""
        # Older than anything put since: in front, in their order.
        self._events.extendleft(reversed(unsent.events))
        self._drop_overflow()
        for drive, telemetry in unsent.states.items():
            self._states.setdefault(drive, telemetry)  # a newer state wins
        for drive, online in unsent.availability.items():
            self._availability.setdefault(drive, online)
        if self._states or self._availability or self._events:
            self._ready.set()

    def _drop_overflow(self) -> None:
        while len(self._events) > self._max_events:
            self._events.popleft()  # the oldest: the newest tell the current story
            self.stats.events_dropped += 1
            if self.stats.events_dropped % DROP_LOG_EVERY == 1:
                log.warning(
                    "MQTT: %d events waiting for the broker (queue_size): %d dropped so far",
                    self._max_events,
                    self.stats.events_dropped,
                )
