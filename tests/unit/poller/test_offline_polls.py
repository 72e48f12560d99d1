"""How often the poller asks a drive that went silent, on a real bus and a simulated line: less
and less while it is offline (each poll answered 0x0B at once by the bus, counted on /metrics as
`offline_rejected`), and at its poll group's own interval again once it answers."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from dataclasses import dataclass, field

import pytest

from gateway.bus import Bus
from gateway.config import DriveConfig
from gateway.instruments.simulator import SimulatedLine
from gateway.poller import Poller
from gateway.poller.drive_state import DriveEvent
from gateway.profile.telemetry import Telemetry
from gateway.routing import Router
from gateway.settings import drive_route, drive_settings
from gateway.tasks import ServiceTasks
from tests.support import eventually, running_bus

pytestmark = pytest.mark.line(addresses=[1])

INTERVAL_S = 0.1
"""The drive's one poll group: state word 1, state word 2 and the fault code, every 100 ms."""
WINDOW_S = 3.0
"""Polled at its interval, the drive would be asked 30 times in this window."""


@dataclass
class Heard:
    """What a dashboard hears of the drive: its states and its availability."""

    states: int = 0
    availability: list[bool] = field(default_factory=list)

    def state_updated(self, drive: str, telemetry: Telemetry) -> None:
        self.states += 1

    def availability_changed(self, drive: str, online: bool) -> None:
        self.availability.append(online)

    def drive_event(self, event: DriveEvent) -> None:
        pass


@dataclass
class Polled:
    bus: Bus
    heard: Heard


@pytest.fixture
async def polled(line: SimulatedLine) -> AsyncIterator[Polled]:
    """The drive polled by a poller of its own: one failed request takes it offline, and the
    bus probes it at least every 2 s (`probe_initial_s`) to find it back."""
    async with (
        running_bus(line.path, timeout_ms=50, retries=0, offline_after=1, probe_max_s=0.2) as bus,
        asyncio.TaskGroup() as group,
    ):
        group_of_the_service = ServiceTasks()
        group_of_the_service.bind(group)
        drive = drive_settings(
            DriveConfig.model_validate(
                {
                    "name": "pump1",
                    "bus": "line1",
                    "address": 1,
                    "model": "gd350",
                    "poll": [
                        {
                            "name": "state",
                            "start": 0x2100,
                            "count": 3,
                            "interval_ms": INTERVAL_S * 1000,
                        }
                    ],
                }
            )
        )
        router = Router([drive_route(drive, bus)], [bus])
        poller = Poller([drive], router, group_of_the_service)
        heard = Heard()
        poller.add_listener(heard)
        bus.add_listener(router.on_drive_health)
        bus.add_listener(poller.on_drive_health)
        await poller.start()
        try:
            yield Polled(bus, heard)
        finally:
            await poller.stop()


async def states_in(heard: Heard, seconds: float) -> int:
    before = heard.states
    await asyncio.sleep(seconds)  # the thing under test: polls answered over a window
    return heard.states - before


async def test_a_dead_drive_is_polled_less_and_less_and_at_its_interval_once_it_answers(
    polled: Polled, line: SimulatedLine
) -> None:
    await eventually(lambda: polled.heard.availability == [True], what="the drive online")
    normal = await states_in(polled.heard, 1.0)
    assert normal >= 5, f"{normal} answered polls in 1 s at a {INTERVAL_S} s interval"

    line.set_dead(1, True)
    await eventually(lambda: polled.heard.availability[-1:] == [False], what="the drive offline")
    rejected = polled.bus.stats.offline_rejected
    await asyncio.sleep(WINDOW_S)  # the thing under test: polls of an offline drive over a window
    asked = polled.bus.stats.offline_rejected - rejected
    # Its interval doubled at once and after every poll: 0.2, 0.4, 0.8, 1.6 s (jittered down to
    # a fifth less), so four or five polls; never none, or it would never be seen back by a poll.
    assert 1 <= asked <= 6, f"an offline drive polled {asked} times in {WINDOW_S} s"

    line.set_dead(1, False)
    await eventually(
        lambda: polled.heard.availability[-1:] == [True], within_s=5.0, what="the drive back"
    )
    again = await states_in(polled.heard, 1.0)
    # Back at its own interval at once: no wait left over from the backoff.
    assert again >= normal * 0.6, f"{again} answered polls in 1 s back online, {normal} before"
