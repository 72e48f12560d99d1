"""What the poller hands the MQTT bridge: bounded, never blocking the poller.

The poller must never wait for the broker (it may be down for hours), so handing over is a plain
call that returns at once. States and availabilities are kept per drive, the newest replacing the
older (only the newest matters, and there are as many as drives: bounded by nature). Events don't
come this way: each is worth keeping, through a restart too, so they wait in the store
(`gateway.store`) and the publisher forwards them from there.

What the bridge took but could not publish (the connection broke halfway) it hands back with
`restore`: a state or availability goes back unless a newer one came meanwhile.
"""

from __future__ import annotations

import asyncio
import contextlib
from dataclasses import dataclass, field

from gateway.profile.telemetry import Telemetry


@dataclass(slots=True)
class OutboxStats:
    states: int = 0
    states_superseded: int = 0
    """States replaced by a newer one before the bridge took them (harmless)."""


@dataclass(slots=True)
class Pending:
    states: dict[str, Telemetry] = field(default_factory=dict)
    availability: dict[str, bool] = field(default_factory=dict)

    def __bool__(self) -> bool:
        return bool(self.states or self.availability)


class Outbox:
    def __init__(self) -> None:
        self.stats = OutboxStats()
        self._states: dict[str, Telemetry] = {}
        self._availability: dict[str, bool] = {}
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

    async def wait(self, timeout_s: float) -> None:
        """Until something is pending, or `timeout_s` has passed."""
        if not self._ready.is_set():
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(timeout_s):
                    await self._ready.wait()

    def take(self) -> Pending:
        pending = Pending(self._states, self._availability)
        self._states, self._availability = {}, {}
        self._ready.clear()
        return pending

    def restore(self, unsent: Pending) -> None:
        """Hand back what was taken but not published: it goes out first next time."""
        for drive, telemetry in unsent.states.items():
            self._states.setdefault(drive, telemetry)  # a newer state wins
        for drive, online in unsent.availability.items():
            self._availability.setdefault(drive, online)
        if self._states or self._availability:
            self._ready.set()
