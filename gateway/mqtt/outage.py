"""Running values through a broker outage: kept while a connection is away, delivered once it
is back, beside the live values and never in their way.

    keep     `OutageRecorder` is a poll listener of one connection (a route: `json`, the
             bridge's; `sparkplug`, the edge node's). While its connection can't deliver (lost;
             for Sparkplug also not born, or the primary host offline), each poll's values that
             are news for the drive (all of them at the first poll of an outage) go to the
             store's outage buffer (`gateway.store.outage_buffer`) with the poll's time: at the
             rate polled, bounded by `storage.outage_buffer_mb` and `outage_buffer_hours`
    deliver  `deliver` runs while the connection is up: the kept samples in the order polled,
             a batch of each drive's at a time (`send`: the JSON history message, or a
             historical DDATA), each batch removed from the store once sent; `PACE_S` between
             batches, so live values go first. What the bounds took before delivery comes as a
             `Gap` (`mark`)

Delivery is at least once: a batch sent on a connection that breaks before it is removed goes
again on the next (a consumer that keeps a series by time takes it twice as once).
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Awaitable, Callable, Mapping
from typing import Final

from gateway.profile.telemetry import Telemetry
from gateway.store import EventStore
from gateway.store.outage_rows import Gap, KeptSample, Value

BATCH: Final = 500
"""Samples read from the store at a time (all drives); each drive's go in one message."""
PACE_S: Final = 0.05
"""Between two batches: the live values' turn (20 batches a second at most)."""
IDLE_S: Final = 1.0
"""Nothing kept: look again this often (the store writes what is kept within a second)."""
NOT_KEPT: Final = frozenset({"last_seen"})
"""The sample's time says when."""

Send = Callable[[str, list[KeptSample]], Awaitable[bool]]
"""Publish one drive's samples; False: not now (the drive is being born), try again soon."""
Mark = Callable[[Gap], Awaitable[None]]


class OutageRecorder:
    def __init__(self, route: str, store: EventStore, live: Callable[[], bool]) -> None:
        self.route = route
        self.store = store
        self.live = live
        """Whether the connection delivers values now."""
        self._last: dict[str, Telemetry] = {}
        """Drive → its state at the last poll."""
        self._away: set[str] = set()
        """Drives with samples kept in this outage (the next is news only)."""

    # -- PollListener ---------------------------------------------------------------------------

    def state_updated(self, drive: str, telemetry: Telemetry) -> None:
        last = self._last.get(drive, {})
        self._last[drive] = telemetry  # a new mapping at every poll: kept as it is
        if self.live():
            if self._away:
                self._away.clear()
            return
        reading = {k: v for k, v in telemetry.items() if k not in NOT_KEPT}
        news = reading if drive not in self._away else _news(reading, last)
        self._away.add(drive)
        self.store.keep_sample(self.route, drive, news, time.time())

    def availability_changed(self, drive: str, online: bool) -> None:
        pass

    def drive_event(self, event: object) -> None:
        pass

    # -- the connection back ----------------------------------------------------------------------

    async def deliver(self, send: Send, mark: Mark) -> None:
        """For as long as the connection lasts: what was kept, oldest first."""
        after = 0
        while True:
            for gap in self.store.outage_gaps(self.route):
                await mark(gap)
            samples = await self.store.outage_samples(self.route, after, BATCH)
            if not samples:
                await asyncio.sleep(IDLE_S)
                continue
            by_drive: dict[str, list[KeptSample]] = {}
            for sample in samples:
                by_drive.setdefault(sample.drive, []).append(sample)
            for drive, kept in by_drive.items():
                # A drive being born (its DBIRTH comes first) is a few milliseconds from ready;
                # nothing signals a device's birth, and asking again costs nothing.
                while not await send(drive, kept):  # noqa: ASYNC110
                    await asyncio.sleep(PACE_S)
            after = samples[-1].id
            self.store.outage_delivered(self.route, after)
            await asyncio.sleep(PACE_S)


def _news(reading: Mapping[str, Value], last: Mapping[str, object]) -> dict[str, Value]:
    return {key: value for key, value in reading.items() if key not in last or last[key] != value}
