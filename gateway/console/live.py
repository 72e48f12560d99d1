"""What the console shows live: each bus's figures and each drive's state, charts and events.

Drive state is the poller's: the same decoded state the MQTT bridge publishes (no second poller).
This listens to the poller for charts and events only; the overview reads the poller's state when
it is asked. Bus figures come from the counters the bus keeps anyway (`BusStats`, `DriveStats`),
sampled once a second into a short window: rates are differences over it, so nothing is added to
the bus's work. Each bus's and drive's measured share of the line (`utilisation`: polls, SCADA
and MQTT alike) is shown beside what its polls were planned to take (`planned_utilisation`,
from `gateway.poller.budget.line_plans`, the figure `check-config` prints).
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Final

from gateway.bus import Bus, BusSettings, BusState
from gateway.console.diagnostics import BusCounters
from gateway.console.events import EventStore, GatewayEvent
from gateway.modbus.functions import lookup
from gateway.poller import Poller
from gateway.poller.budget import LinePlan, line_plans
from gateway.poller.drive_state import DriveEvent, EventKind, iso_time
from gateway.profile import STANDARD_EXCEPTIONS, ExceptionNames
from gateway.profile.telemetry import Telemetry
from gateway.settings import DriveSettings
from gateway.store.history import Value, values

HISTORY_S: Final = 15 * 60.0
CHART_STEP_S: Final = 1.0
"""One chart point a second at most: 900 points per drive for 15 minutes, whatever the polls."""
RATE_WINDOW_S: Final = 5.0
"""Transactions per second and utilisation: over the last few seconds, so a change shows soon."""
MINUTE_S: Final = 60.0
CHART_KEYS: Final = ("output_frequency_hz", "output_current_a", "bus_voltage_v")
AUDITED_ELSEWHERE: Final = ("console:", "poll", "probe")
"""The console audits its own writes in words; polls and probes never write."""


@dataclass(frozen=True, slots=True)
class BusSample:
    at: float
    transactions: int
    timeouts: int
    bad_replies: int
    retries: int
    line_s: float
    drives_line_s: Mapping[int, float] = field(default_factory=dict)
    """Address → the line time its transactions took, since the bus started."""


@dataclass(slots=True)
class DriveHistory:
    """The last 15 minutes of a drive's values (`gateway.store.history.values`), a point a
    second at most: the live charts, and the history page's shortest window."""

    points: deque[tuple[float, dict[str, Value]]] = field(
        default_factory=lambda: deque(maxlen=int(HISTORY_S / CHART_STEP_S) + 1)
    )
    last_at: float = 0.0

    def add(self, at: float, found: dict[str, Value]) -> None:
        """The drive's values at `at`; those older than `HISTORY_S` go. The ring's length
        bounds it at a point a second; a drive polled less often (a busy line) would keep
        more than its 15 minutes, and the memory for them grew for as much longer (the soak:
        still growing at 30 minutes)."""
        self.last_at = at
        self.points.append((at, found))
        while self.points[0][0] < at - HISTORY_S:
            self.points.popleft()


class LiveState:
    """A poll listener (`gateway.poller.PollListener`) and the bus sampler, for the console."""

    def __init__(
        self,
        buses: Mapping[str, Bus],
        lines: Sequence[BusSettings],
        drives: Sequence[DriveSettings],
        poller: Poller | None,
        events: EventStore,
    ) -> None:
        self.buses = buses
        self.lines = {b.name: b.line for b in lines}
        self.drives = {d.name: d for d in drives}
        self.poller = poller
        self.events = events
        self.history = {name: DriveHistory() for name in self.drives}
        self._samples: dict[str, deque[BusSample]] = {
            name: deque(maxlen=int(MINUTE_S) + 2) for name in buses
        }
        self._bus_states = {name: bus.state for name, bus in buses.items()}
        self._counters: dict[str, BusCounters] = {}
        self._by_address = {(d.bus, d.address): d.name for d in drives}
        self._exceptions: dict[tuple[str, int], ExceptionNames] = {
            (d.bus, d.address): d.profile.exceptions for d in drives
        }
        self.redundancy: Callable[[], dict[str, Any]] | None = None
        """With `redundancy:`, this box's role (the overview's banner); None: no such thing."""

    # -- poll listener ----------------------------------------------------------------------

    def state_updated(self, drive: str, telemetry: Telemetry) -> None:
        history = self.history.get(drive)
        if history is None:
            return
        now = time.time()
        if now - history.last_at < CHART_STEP_S:
            return
        history.add(now, values(telemetry))

    def availability_changed(self, drive: str, online: bool) -> None:
        pass  # told again as a drive event

    def drive_event(self, event: DriveEvent) -> None:
        drive = self.drives.get(event.drive)
        bus = drive.bus if drive else None
        if event.kind in (EventKind.FAULT_RAISED, EventKind.FAULT_CLEARED):
            data = event.data
            # The description holds the short code already ("OH2: inverter module overheat").
            text = str(data.get("fault_description"))
        elif event.kind is EventKind.DRIVE_OFFLINE:
            text = "offline: no answer"
        else:
            text = "online again"
        self.events.record(GatewayEvent(str(event.kind), text, event.drive, bus, at=event.at))

    # -- the audit of writes from Modbus-TCP and MQTT (a bus request observer) ---------------

    def request_done(
        self,
        bus: str,
        address: int,
        function: int,
        client: str,
        duration_s: float,
        code: int | None,
    ) -> None:
        """A request answered (a bus's request observer, told a `RequestDone`'s fields): a
        write from SCADA or MQTT becomes an audit line."""
        if not lookup(function).writes or client.startswith(AUDITED_ELSEWHERE):
            return
        exceptions = self._exceptions.get((bus, address), STANDARD_EXCEPTIONS)
        result = "ok" if code is None else f"exception {code:02X}H {exceptions.name(code)}"
        target = "broadcast" if address == 0 else f"address {address}"
        self.events.record(
            GatewayEvent(
                "write",
                f"function {function:02X}H to {target}",
                self._by_address.get((bus, address)),
                bus,
                who=client,
                result=result,
            )
        )

    # -- bus sampling (once a second, from the console's own task) --------------------------

    def sample_buses(self) -> None:
        now = time.monotonic()
        for name, bus in self.buses.items():
            stats = bus.stats
            line_s = {address: d.line_s for address, d in list(bus.drive_stats.items())}
            self._samples[name].append(
                BusSample(
                    now,
                    stats.transactions,
                    stats.timeouts,
                    sum(stats.bad_replies.values()),
                    stats.retries,
                    sum(line_s.values()),
                    line_s,
                )
            )
            self._count(name, bus, now)
            self._bus_state_event(name, bus)

    def _count(self, name: str, bus: Bus, now: float) -> None:
        counters = self._counters.get(name)
        if counters is None or counters.stats is not bus.stats:  # new, or replaced by a reload
            counters = self._counters[name] = BusCounters(bus.stats)
        counters.sample(now, bus.drive_stats)

    def _bus_state_event(self, name: str, bus: Bus) -> None:
        before, now = self._bus_states[name], bus.state
        if before == now:
            return
        self._bus_states[name] = now
        if now is BusState.REOPENING:
            self.events.record(
                GatewayEvent("port_lost", f"port {bus.settings.line.port} lost", bus=name)
            )
        elif now is BusState.OPEN and before is BusState.REOPENING:
            self.events.record(
                GatewayEvent("port_back", f"port {bus.settings.line.port} open again", bus=name)
            )

    # -- what the pages show ----------------------------------------------------------------

    def overview(self) -> dict[str, Any]:
        plans = self.line_plans()  # once: every drive's row takes its share from it
        return {
            "time": iso_time(time.time()),
            "buses": [self.bus_view(name, plans) for name in self.buses],
            "drives": [self.drive_view(name, plans) for name in self.drives],
            "store_problem": self.events.store_problem(),
            "redundancy": None if self.redundancy is None else self.redundancy(),
        }

    def line_plans(self) -> dict[str, LinePlan]:
        """Bus → what the drives polled now (a reload's included) were planned to take of it,
        at its settings now (a reload may have changed its baud rate)."""
        polled = [] if self.poller is None else [d.settings for d in self.poller.drives.values()]
        return line_plans((bus.settings for bus in self.buses.values()), polled)

    def bus_view(self, name: str, plans: Mapping[str, LinePlan] | None = None) -> dict[str, Any]:
        plan = (plans or self.line_plans())[name]
        bus = self.buses[name]
        line = self.lines[name]
        chars = line.char_format
        samples = self._samples[name]
        recent = _window(samples, RATE_WINDOW_S)
        minute = _window(samples, MINUTE_S)
        return {
            "name": name,
            "state": str(bus.state),
            "port": line.port,
            "format": f"{chars.baudrate} {chars.bytesize}{chars.parity}{chars.stopbits}",
            "utilisation": _rate(recent, "line_s"),
            "planned_utilisation": _share(plan.total.busy_fraction),
            "over_budget": plan.over_budget,
            "transactions_per_s": _rate(recent, "transactions"),
            "timeouts_per_min": _delta(minute, "timeouts"),
            "bad_replies_per_min": _delta(minute, "bad_replies"),
            "retries_per_min": _delta(minute, "retries"),
            "queue_depth": bus.queue_depth,
        }

    def line_counters(self) -> list[dict[str, Any]]:
        """Per bus and per drive: what the line did since the gateway started, and in the last
        minute (the diagnostics page)."""
        shown = []
        for name, bus in self.buses.items():
            counters = self._counters.get(name)
            if counters is None or counters.stats is not bus.stats:
                counters = BusCounters(bus.stats)  # not sampled yet: since start only
            names = {
                address: drive for (on, address), drive in self._by_address.items() if on == name
            }
            exceptions = {
                address: words for (on, address), words in self._exceptions.items() if on == name
            }
            view = counters.view(bus.drive_stats, names, exceptions)
            line = bus.line
            hardware = {  # what the adapter does to replies, since start (as /metrics has it)
                "glitch_bytes": line.garbage_bytes,
                "echoes": line.echoes,
                "longest_reply_silence_ms": round(line.longest_reply_silence_s * 1000, 1),
            }
            shown.append({**self.bus_view(name), **view, "line": hardware})
        return shown

    def drive_view(self, name: str, plans: Mapping[str, LinePlan] | None = None) -> dict[str, Any]:
        drive = self.drives[name]
        telemetry = self.telemetry(name)
        online = None if self.poller is None else self.poller.availability(name)
        state = telemetry.get("state")
        recent = _window(self._samples[drive.bus], RATE_WINDOW_S)
        planned = (plans or self.line_plans())[drive.bus].drives.get(name)
        return {
            "name": name,
            "unit_id": drive.unit_id,
            "bus": drive.bus,
            "address": drive.address,
            "model": drive.model,
            "online": online,
            "state": None if state is None else str(state).replace("_", " "),
            "fault_name": telemetry.get("fault_name"),
            "fault_description": telemetry.get("fault_description"),
            "output_frequency_hz": telemetry.get("output_frequency_hz"),
            "output_current_a": telemetry.get("output_current_a"),
            "last_answer": telemetry.get("last_seen"),
            "utilisation": _drive_rate(recent, drive.address),
            "planned_utilisation": _share(0.0 if planned is None else planned.busy_fraction),
        }

    def telemetry(self, name: str) -> Telemetry:
        if self.poller is None or name not in self.poller.drives:
            return {}
        return self.poller.telemetry(name)

    def chart(self, name: str) -> dict[str, Any]:
        """The last 15 minutes, as columns (what uPlot takes): time in epoch seconds."""
        points = list(self.history[name].points)
        columns: list[list[float | None]] = [[at for at, _ in points]]
        columns += [[_number(found.get(key)) for _, found in points] for key in CHART_KEYS]
        return {"keys": ["time", *CHART_KEYS], "columns": columns}

    def recent_values(
        self, name: str, since: float, until: float
    ) -> list[tuple[float, dict[str, Value]]]:
        """The drive's values a second apart from `since` to before `until` (the last 15
        minutes at most), oldest first."""
        return [(at, found) for at, found in self.history[name].points if since <= at < until]


def _number(value: object) -> float | None:
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else None


def _window(samples: deque[BusSample], span_s: float) -> tuple[BusSample, BusSample] | None:
    if len(samples) < 2:
        return None
    last = samples[-1]
    first = next((s for s in samples if last.at - s.at <= span_s + 0.5), samples[0])
    return (first, last) if first is not last else None


def _rate(window: tuple[BusSample, BusSample] | None, key: str) -> float:
    if window is None:
        return 0.0
    first, last = window
    elapsed = last.at - first.at
    change = float(getattr(last, key) - getattr(first, key))
    return round(change / elapsed, 3) if elapsed > 0 else 0.0


def _drive_rate(window: tuple[BusSample, BusSample] | None, address: int) -> float:
    """The share of the line one address's transactions took over the window."""
    if window is None:
        return 0.0
    first, last = window
    elapsed = last.at - first.at
    change = last.drives_line_s.get(address, 0.0) - first.drives_line_s.get(address, 0.0)
    return round(change / elapsed, 3) if elapsed > 0 else 0.0


def _share(fraction: float) -> float:
    """A planned share as the measured ones are given (a fraction, to a thousandth)."""
    return round(fraction, 3)


def _delta(window: tuple[BusSample, BusSample] | None, key: str) -> int:
    if window is None:
        return 0
    first, last = window
    return int(getattr(last, key) - getattr(first, key))
