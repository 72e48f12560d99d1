"""The routing room on a real bus and a simulated line (a pty): the cache is read through,
written through, filled by polls only, and forgotten when the bus isolates a drive."""

from __future__ import annotations

import asyncio
import struct
from collections.abc import AsyncIterator

import pytest

from gateway.bus import Bus
from gateway.errors import DriveOffline, GatewayTargetFailed
from gateway.instruments.simulator import SimulatedLine
from gateway.routing import Route, Router
from tests.support import read_pdu, running_bus, write_pdu

pytestmark = pytest.mark.line(addresses=[1])

STATE = 0x2100
"""State word 1, state word 2, fault code: what a drive's poll reads first."""
ACCEL_TIME = 0x0005


@pytest.fixture
async def bus(line: SimulatedLine) -> AsyncIterator[Bus]:
    # Not tighter: a drive set to answer in 20 ms took 65 on a loaded 2-core machine, and a
    # timeout there made the poll-before-write test fail for what it does not test.
    async with running_bus(line.path, timeout_ms=250, retries=0, offline_after=1) as bus:
        yield bus


def routed(bus: Bus, cache_max_age_s: float | None = 60.0) -> tuple[Router, Route]:
    route = Route(unit_id=1, drive="pump1", bus=bus, address=1, cache_max_age_s=cache_max_age_s)
    router = Router([route], [bus])
    bus.add_listener(router.on_drive_health)
    return router, route


def words(reply: bytes | None) -> list[int]:
    assert reply is not None
    assert not reply[0] & 0x80, reply
    return list(struct.unpack(f">{reply[1] // 2}H", reply[2:]))


async def test_a_read_inside_what_was_polled_is_answered_from_the_cache(
    bus: Bus, line: SimulatedLine
) -> None:
    router, route = routed(bus)
    polled = words(await router.poll(route, STATE, 3))
    before = line.stats["requests"]
    for _ in range(5):
        assert words(await router.execute(1, read_pdu(STATE + 1, 2), client="tcp:a")) == polled[1:]
    assert line.stats["requests"] == before  # not one of them reached the line
    assert router.cache.hits == 5
    # A word that was never polled goes to the drive.
    assert words(await router.execute(1, read_pdu(0x2103), client="tcp:a")) == [
        line.drives[1].identification
    ]
    assert line.stats["requests"] == before + 1


async def test_a_drive_without_a_cache_age_is_always_asked(bus: Bus, line: SimulatedLine) -> None:
    router, route = routed(bus, cache_max_age_s=None)
    await router.poll(route, STATE, 3)
    before = line.stats["requests"]
    await router.execute(1, read_pdu(STATE, 3), client="tcp:a")
    assert line.stats["requests"] == before + 1


async def test_a_poll_always_asks_the_drive_even_when_the_cache_is_fresh(
    bus: Bus, line: SimulatedLine
) -> None:
    router, route = routed(bus)
    assert words(await router.poll(route, STATE, 3))[2] == 0
    line.inject_fault(1, 35)  # the drive trips by itself: nothing went through the gateway
    before = line.stats["requests"]
    assert words(await router.poll(route, STATE, 3))[2] == 35
    assert line.stats["requests"] == before + 1
    # ... and what the poll found is what the next read is answered from.
    assert words(await router.execute(1, read_pdu(STATE + 2), client="tcp:a")) == [35]


async def test_a_write_is_carried_through_and_the_next_read_asks_the_drive(
    bus: Bus, line: SimulatedLine
) -> None:
    router, route = routed(bus)
    old = words(await router.poll(route, ACCEL_TIME, 1))
    assert old != [4321]
    reply = await router.request(route, write_pdu(ACCEL_TIME, 4321), client="mqtt")
    assert reply == write_pdu(ACCEL_TIME, 4321)
    before = line.stats["requests"]
    assert words(await router.execute(1, read_pdu(ACCEL_TIME), client="tcp:a")) == [4321]
    assert line.stats["requests"] == before + 1  # from the drive, not the cache


async def test_a_poll_issued_before_a_write_is_answered_is_not_kept(
    bus: Bus, line: SimulatedLine
) -> None:
    router, route = routed(bus)
    line.set_reply_delay(1, 20)  # the line is busy long enough for both to queue behind
    occupier = asyncio.create_task(router.execute(1, read_pdu(0x3000), client="tcp:a"))
    poll = asyncio.create_task(router.poll(route, ACCEL_TIME, 1))
    write = asyncio.create_task(router.request(route, write_pdu(ACCEL_TIME, 77), client="tcp:b"))
    await asyncio.gather(occupier, poll, write)
    line.set_reply_delay(1, 0)
    before = line.stats["requests"]
    # Whatever the poll read, the cache did not keep it: the read asks the drive.
    assert words(await router.execute(1, read_pdu(ACCEL_TIME), client="tcp:a")) == [77]
    assert line.stats["requests"] == before + 1
    assert router.cache.discarded == 1


async def test_a_broadcast_write_forgets_what_every_drive_said(
    bus: Bus, line: SimulatedLine
) -> None:
    router, route = routed(bus)
    assert words(await router.poll(route, ACCEL_TIME, 1)) != [99]
    assert await router.execute(0, write_pdu(ACCEL_TIME, 99), client="tcp:a") is None
    assert words(await router.execute(1, read_pdu(ACCEL_TIME), client="tcp:a")) == [99]
    assert router.cache.hits == 0


async def test_a_drive_its_bus_isolates_is_never_answered_from_the_cache(
    bus: Bus, line: SimulatedLine
) -> None:
    router, route = routed(bus)
    await router.poll(route, STATE, 3)
    line.set_dead(1, True)
    with pytest.raises(GatewayTargetFailed):  # and the bus isolates it (offline_after 1)
        await router.poll(route, 0x3000, 1)
    assert bus.health.is_offline(1)
    with pytest.raises(DriveOffline):
        await router.execute(1, read_pdu(STATE, 3), client="tcp:a")
    assert router.cache.hits == 0
