"""The poller: one loop per drive reading its poll groups through the router, at poll priority.

The poller only schedules: it asks the router to `poll` (the router carries the read at
`Priority.POLL` through the same bus queue as SCADA, so a SCADA write or read is always served
before any waiting poll, and keeps the answer in its cache). Each answer goes into the drive's
state; listeners (the MQTT bridge) hear of every new state and event through plain calls that
must not block.

Whether a drive is online is the bus's call, not the poller's: the bus counts every failed
transaction to the drive (SCADA's too) against its `offline_after` and tells its listeners
(`on_drive_health`); /health reads the same tracker, so MQTT availability and /health always
agree. A failed poll the bus doesn't count as the drive going offline changes nothing here; an
answered poll marks the drive online. An offline drive's polls back off (`gateway.backoff`, as
the bus's probes and the MQTT connection do): each group's interval doubled as the drive goes
offline and again after each poll, up to `OFFLINE_POLL_MAX_S` (such polls cost no bus time, the
bus answers 0x0B at once, but there is no point asking often). When the bus's probe finds the
drive back it is polled at once, and at its groups' own intervals from then on.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import struct
import time
from collections.abc import Awaitable, Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Final, Protocol

from gateway.backoff import Backoff
from gateway.errors import BusClosed, DriveOffline, GatewayPathUnavailable, GatewayTargetFailed
from gateway.modbus.functions import is_exception
from gateway.poller.drive_state import DriveEvent, DriveState
from gateway.poller.plan import PollBlock, PollSchedule, poll_schedules
from gateway.profile import format_register
from gateway.profile.point_types import word_key
from gateway.profile.telemetry import Telemetry
from gateway.routing import Route, Router
from gateway.settings import DriveSettings
from gateway.tasks import ServiceTasks, cancel_and_wait

log = logging.getLogger(__name__)

OFFLINE_POLL_MAX_S: Final = 30.0
STOP_BUDGET_S: Final = 0.5


class PollListener(Protocol):
    """Told of what polls find; called on the event loop, must return at once."""

    def state_updated(self, drive: str, telemetry: Telemetry) -> None: ...

    def availability_changed(self, drive: str, online: bool) -> None: ...

    def drive_event(self, event: DriveEvent) -> None: ...


@dataclass(slots=True)
class _GroupTimer:
    schedule: PollSchedule
    offline_waits: Backoff
    """The waits between this group's polls while the drive is offline: twice its interval,
    doubling, up to `OFFLINE_POLL_MAX_S` (or the interval, when that is longer)."""
    next_at: float = 0.0


def _group_timer(schedule: PollSchedule) -> _GroupTimer:
    cap_s = max(schedule.interval_s, OFFLINE_POLL_MAX_S)
    return _GroupTimer(schedule, Backoff(min(2 * schedule.interval_s, cap_s), cap_s))


@dataclass(slots=True)
class PolledDrive:
    settings: DriveSettings
    route: Route
    state: DriveState
    timers: list[_GroupTimer]
    lock: asyncio.Lock = field(default_factory=asyncio.Lock)
    wake: asyncio.Event = field(default_factory=asyncio.Event)
    polls: int = 0
    failed_polls: int = 0
    """In a row, for diagnostics: whether the drive is offline is its bus's call."""
    reported_exceptions: set[tuple[int, int]] = field(default_factory=set)
    removed: bool = False
    """A reload removed it: its loop ends."""

    @property
    def offline_backoff(self) -> int:
        """How far its polls have backed off while offline: the most doublings of a group."""
        return max((timer.offline_waits.doublings for timer in self.timers), default=0)

    def back_to_normal(self) -> None:
        """It answered (or is about to be asked at once): its groups' next waits are their own
        intervals again."""
        for timer in self.timers:
            timer.offline_waits.reset()


class Poller:
    def __init__(
        self, drives: Iterable[DriveSettings], router: Router, tasks: ServiceTasks
    ) -> None:
        self.router = router
        self.tasks = tasks
        self.drives: dict[str, PolledDrive] = {}
        self._by_bus_address: dict[tuple[str, int], str] = {}
        for settings in drives:
            self._polled(settings)
        self._listeners: list[PollListener] = []
        self._task: asyncio.Task[None] | None = None
        self._added: dict[str, asyncio.Task[None]] = {}
        """Drives added by a reload: each polled by its own task in the service's TaskGroup."""
        self.polls = 0
        self.poll_failures = 0
        self.read_max_frequency = False
        """Read each drive's P00.03 at start (for Home Assistant's set-point maximum)."""
        self.max_frequency_hz: dict[str, float] = {}
        """Drive name → its P00.03, for the drives that answered at start."""
        self.open_faults: Callable[[], Awaitable[Mapping[str, int]]] | None = None
        """Asked at each start: each drive's fault the last run left open (the store's; with
        `redundancy:` and MQTT, what the active box told the consumers, over it)."""

    def _polled(self, settings: DriveSettings) -> PolledDrive:
        timers = [_group_timer(s) for s in poll_schedules(settings)]
        route = self.router.route_for_drive(settings.name)
        state = DriveState(settings.name, settings.profile, settings.alarms)
        drive = PolledDrive(settings, route, state, timers)
        self.drives[settings.name] = drive
        self._by_bus_address[(settings.bus, settings.address)] = settings.name
        return drive

    def add_listener(self, listener: PollListener) -> None:
        self._listeners.append(listener)

    def remove_listener(self, listener: PollListener) -> None:
        if listener in self._listeners:
            self._listeners.remove(listener)

    # -- lifecycle ---------------------------------------------------------------------------

    async def start(self) -> None:
        if self.open_faults is not None:
            for name, code in (await self.open_faults()).items():
                if name in self.drives:
                    self.drives[name].state.fault_before_start = code
        if self.read_max_frequency:
            from gateway.poller.max_frequency import read_max_frequencies

            drives = [drive.settings for drive in self.drives.values()]
            self.max_frequency_hz = await read_max_frequencies(self.router, drives)
        self._task = self.tasks.start("poller", self._run())

    async def stop(self) -> None:
        for task in self._added.values():
            task.cancel()
        if self._task is not None:
            await cancel_and_wait(self._task, STOP_BUDGET_S)
            self._task = None
        for task in list(self._added.values()):
            await cancel_and_wait(task, STOP_BUDGET_S)
        self._added.clear()

    # -- a reload ----------------------------------------------------------------------------

    def add_drive(self, settings: DriveSettings) -> None:
        """Poll a drive a reload added (its route is in the router already)."""
        drive = self._polled(settings)
        if drive.timers:
            name = settings.name
            self._added[name] = self.tasks.start(f"poller:{name}", self._poll_forever(drive))

    def remove_drive(self, name: str) -> None:
        """Stop polling a drive a reload removed; a poll on the wire finishes on its own."""
        drive = self.drives.pop(name, None)
        if drive is None:
            return
        self._by_bus_address.pop((drive.settings.bus, drive.settings.address), None)
        drive.removed = True
        drive.wake.set()
        task = self._added.pop(name, None)
        if task is not None:
            task.cancel()

    def forget_readings(self) -> None:
        """A redundant box takes the line over: what it polled before it last left the line is
        stale. Each drive's first poll then compares its fault with `open_faults` (what the
        old active told), not with a fault this box saw long ago."""
        for drive in self.drives.values():
            drive.state.registers.clear()
            drive.state.online = None

    def reroute(self) -> None:
        """A reload reopened buses: each drive's route again from the router (its new bus)."""
        for name, drive in self.drives.items():
            drive.route = self.router.route_for_drive(name)

    async def _run(self) -> None:
        async with asyncio.TaskGroup() as tasks:
            for name, drive in self.drives.items():
                if drive.timers:
                    tasks.create_task(self._poll_forever(drive), name=f"poller:{name}")

    # -- what other parts call ---------------------------------------------------------------

    def on_drive_health(self, bus: str, address: int, online: bool) -> None:
        """Bus listener: a drive went offline, or its probe found it back."""
        name = self._by_bus_address.get((bus, address))
        if name is None:
            return
        drive = self.drives[name]
        if online:
            self._poll_soon(drive)  # the poll's answer is what marks it online
        else:
            self._set_online(drive, False)

    def poll_now(self, name: str) -> None:
        """Poll drive `name` again now (a command wrote to it: show its new state at once)."""
        drive = self.drives.get(name)
        if drive is not None:
            self._poll_soon(drive)

    async def refresh(self, name: str) -> Telemetry:
        """Poll every group of drive `name` now; its telemetry afterwards."""
        drive = self.drives[name]
        for timer in drive.timers:
            await self._poll_group(drive, timer.schedule)
        return drive.state.telemetry()

    def telemetry(self, name: str) -> Telemetry:
        return self.drives[name].state.telemetry()

    def availability(self, name: str) -> bool | None:
        return self.drives[name].state.online

    # -- the loop ----------------------------------------------------------------------------

    async def _poll_forever(self, drive: PolledDrive) -> None:
        while not drive.removed:
            now = time.monotonic()
            for timer in drive.timers:
                if timer.next_at <= now:
                    try:
                        await self._poll_group(drive, timer.schedule)
                    except Exception:
                        # A bug must not end this drive's polling for good: say it loudly, go on.
                        name = drive.settings.name
                        log.exception("poll of %s (%s) failed", name, timer.schedule.group)
                    timer.next_at = self._next_poll_at(drive, timer, now)
            delay = min(t.next_at for t in drive.timers) - time.monotonic()
            if delay > 0:
                with contextlib.suppress(TimeoutError):
                    async with asyncio.timeout(delay):
                        await drive.wake.wait()
            drive.wake.clear()

    def _next_poll_at(self, drive: PolledDrive, timer: _GroupTimer, now: float) -> float:
        if drive.state.online is False:
            return now + timer.offline_waits.next_delay()
        interval = timer.schedule.interval_s
        # Keep the rhythm; when behind it (a busy bus, a poll asked for now), restart from now.
        scheduled = timer.next_at + interval
        return scheduled if scheduled > now else now + interval

    def _poll_soon(self, drive: PolledDrive) -> None:
        drive.back_to_normal()
        for timer in drive.timers:
            timer.next_at = 0.0
        drive.wake.set()

    async def _poll_group(self, drive: PolledDrive, schedule: PollSchedule) -> None:
        async with drive.lock:  # a refresh and the loop never read the same drive at once
            for block in schedule.blocks:
                if not await self._poll_block(drive, block):
                    return

    async def _poll_block(self, drive: PolledDrive, block: PollBlock) -> bool:
        """Read one block; False when the drive gave no answer (skip the rest of the group).

        While SCADA reads wait for the line, a long block is read in shorter pieces
        (`PollBlock.pieces_while_reads_wait`): each poll holds the waiting readers up for its
        own transaction. Its values are taken in once all pieces are answered, as one read's."""
        pieces = block.pieces_while_reads_wait() if drive.route.bus.reads_waiting else (block,)
        values: list[int] = []
        for piece in pieces:
            reply = await self._read(drive, piece)
            if isinstance(reply, bool):
                return reply
            if is_exception(reply):
                self._drive_refused(drive, piece, reply[1] if len(reply) > 1 else 0)
                return True
            values += _values(piece, reply)
        self._answered(drive, word_key(block.table, block.start), values)
        return True

    async def _read(self, drive: PolledDrive, block: PollBlock) -> bytes | bool:
        """One poll's reply PDU (an exception reply too); False when the drive gave no answer,
        True when the bus had no room for it (the next interval tries again)."""
        name = drive.settings.name
        self.polls += 1
        drive.polls += 1
        try:
            return await self.router.poll(drive.route, block.start, block.count, block.function)
        except BusClosed:
            return False  # shutting down: not the drive's failure, nothing to count
        except DriveOffline:
            self._poll_failed(drive, offline_on_bus=True)
            return False
        except GatewayTargetFailed as exc:
            log.debug("poll of %s at %s: %s", name, format_register(block.start), exc)
            self._poll_failed(drive, offline_on_bus=False)
            return False
        except GatewayPathUnavailable as exc:
            # Queue full: the bus is busy with more urgent work; the next interval tries again.
            log.debug("poll of %s skipped: %s", name, exc)
            return True

    def _answered(self, drive: PolledDrive, start: int, words: list[int]) -> None:
        drive.failed_polls = 0
        drive.back_to_normal()
        was_online = drive.state.online
        events = drive.state.record_poll(start, words, time.time())
        if was_online is not True:
            self._tell_availability(drive)
        self._tell_events(events)
        telemetry = drive.state.telemetry()
        for listener in self._listeners:
            listener.state_updated(drive.settings.name, telemetry)

    def _poll_failed(self, drive: PolledDrive, *, offline_on_bus: bool) -> None:
        self.poll_failures += 1
        drive.failed_polls += 1
        if offline_on_bus and drive.state.online is not False:
            # The bus has isolated it (its listener call usually came first): agree with it.
            # A poll that merely failed is one of the bus's `offline_after`, not a verdict.
            self._set_online(drive, False)

    def _set_online(self, drive: PolledDrive, online: bool) -> None:
        events = drive.state.set_online(online)
        if events:
            log.warning("drive %s is %s", drive.settings.name, "online" if online else "offline")
            self._tell_availability(drive)
            self._tell_events(events)

    def _drive_refused(self, drive: PolledDrive, block: PollBlock, code: int) -> None:
        # The drive answered, so it is there; the block is wrong for this model. Say so once.
        key = (block.start, code)
        if key not in drive.reported_exceptions:
            drive.reported_exceptions.add(key)
            log.warning(
                "drive %s refuses the poll of %d words at %s: exception %02XH %s",
                drive.settings.name,
                block.count,
                format_register(block.start),
                code,
                drive.settings.profile.exceptions.name(code),
            )

    def _tell_availability(self, drive: PolledDrive) -> None:
        online = drive.state.online
        if online is None:
            return
        for listener in self._listeners:
            listener.availability_changed(drive.settings.name, online)

    def _tell_events(self, events: list[DriveEvent]) -> None:
        for event in events:
            for listener in self._listeners:
                listener.drive_event(event)


def _values(block: PollBlock, reply: bytes) -> list[int]:
    """A read's words, or its bits as 0 and 1 (first bit: the low bit of the first byte)."""
    if block.table.bits:
        return [reply[2 + n // 8] >> (n % 8) & 1 for n in range(block.count)]
    return list(struct.unpack(f">{(len(reply) - 2) // 2}H", reply[2:]))
