"""The gateway's own events as the console shows them: faults raised and cleared, drives offline
and online, ports lost and back, and the audit: logins, failed logins, logouts and writes.

Each audit event carries what IEC 62443-4-2 CR 2.8 asks of one: its time, its source (the
user and the client's address), its category (`Category`), its type, its id (the store's, once
stored) and its result. Passwords are never part of one.

The console reads and writes them only through `EventStore`, a small interface: today an
in-memory ring (`MemoryEventStore`, bounded, lost at restart); a store that survives restarts
(the "Nothing lost" issue) plugs in by implementing the same two methods.
"""

from __future__ import annotations

import csv
import io
import itertools
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace
from datetime import datetime
from enum import StrEnum
from typing import Any, Final, Protocol

from gateway.console.spreadsheet import cell
from gateway.poller.drive_state import iso_time
from gateway.store.modbus_writes import client_host
from gateway.store.records import FaultRecord, StoredEvent
from gateway.store.status import StoreStatus

MEMORY_EVENTS = 2000


class Category(StrEnum):
    """What an audit event is about (CR 2.8's "event category")."""

    AUTHENTICATION = "authentication"
    """Logins, failed logins, logouts."""
    CONTROL = "control"
    """Commands and set-points: what a drive does now."""
    CONFIGURATION = "configuration"
    """Parameter writes: how a drive behaves from now on."""


AUDIT_KINDS: Final = {
    "login": Category.AUTHENTICATION,
    "login_failed": Category.AUTHENTICATION,
    "logout": Category.AUTHENTICATION,
    "config_changed": Category.CONFIGURATION,
}
"""The console's own audit events beside its writes, stored under the same type."""


@dataclass(frozen=True, slots=True)
class GatewayEvent:
    kind: str
    """fault_raised, fault_cleared, drive_offline, drive_online, port_lost, port_back, write."""
    text: str
    """In words: "OL1: inverter overload", "control word = 1 (run_forward) → ok"."""
    drive: str | None = None
    bus: str | None = None
    who: str | None = None
    """For writes: "console:alice", "tcp:10.0.0.5:40112", "mqtt"; for logins the name."""
    result: str | None = None
    at: float = field(default_factory=time.time)
    address: str | None = None
    """The console client's address, for its audit events."""
    category: str | None = None
    """An audit event's `Category`."""
    id: int | None = None
    """The store's id (once stored: the same as on `<base>/bridge/event`)."""
    type: str | None = None
    """The store's type (`command`, `modbus_writes`...); None: the same as `kind`."""
    pending: bool = False
    """A Modbus-TCP write not yet in its minute's `modbus_writes` event (shown meanwhile)."""

    @property
    def store_type(self) -> str:
        if self.type is not None:
            return self.type
        if self.kind == "write":
            return "modbus_writes" if (self.who or "").startswith("tcp:") else "command"
        return self.kind

    @property
    def user(self) -> str | None:
        """An audit event's user: the name without the console's prefix."""
        return self.who.removeprefix("console:") if self.who else None

    def to_json(self) -> dict[str, Any]:
        data = asdict(self)
        data["time"] = iso_time(self.at)
        data["type"] = self.store_type
        data["user"] = self.user if self.category is not None else None
        return data


KIND_TYPES: Final = {"write": ("command", "modbus_writes")}
"""A kind the pages show that stands for several of the store's types."""


@dataclass(frozen=True, slots=True)
class EventQuery:
    """Which events: of one drive (and the line-wide ones), of some kinds, in a time range."""

    drive: str | None = None
    kinds: frozenset[str] = frozenset()
    """The pages' kinds (`write`, `fault_raised`...) or the store's types (`modbus_writes`)."""
    since: float | None = None
    """Epoch seconds, inclusive."""
    until: float | None = None
    """Epoch seconds, exclusive."""

    def types(self) -> tuple[str, ...]:
        """The store's types that answer the kinds asked for (empty: every type)."""
        return tuple(sorted({t for kind in self.kinds for t in KIND_TYPES.get(kind, (kind,))}))

    def matches(self, event: GatewayEvent) -> bool:
        if self.drive is not None and event.drive != self.drive:
            return False
        if self.kinds and not {event.kind, event.store_type} & self.kinds:
            return False
        if self.since is not None and event.at < self.since:
            return False
        return self.until is None or event.at < self.until


class EventStore(Protocol):
    def record(self, event: GatewayEvent) -> None:
        """Keep `event`; must return at once (called on the event loop)."""

    def recent(self, drive: str | None = None, limit: int = 200) -> list[GatewayEvent]:
        """The newest first; only `drive`'s (and the line-wide ones of no drive) when given."""

    async def history(self, query: EventQuery, limit: int = 200) -> list[GatewayEvent]:
        """The newest first, as `query` asks, from wherever the events are kept longest (across
        restarts, if kept): each event once."""

    async def recorded_faults(self, drive: str, limit: int) -> list[dict[str, Any]]:
        """The faults recorded for `drive` (raised, cleared, duration, snapshot), newest first;
        empty where nothing keeps them."""

    def store_problem(self) -> str | None:
        """Why events are not kept on disk now (the console's banner); None when they are, or
        where nothing was meant to keep them."""


class MemoryEventStore:
    def __init__(self, size: int = MEMORY_EVENTS) -> None:
        self._events: deque[GatewayEvent] = deque(maxlen=size)

    def record(self, event: GatewayEvent) -> None:
        self._events.append(event)

    def recent(self, drive: str | None = None, limit: int = 200) -> list[GatewayEvent]:
        found: list[GatewayEvent] = []
        for event in reversed(self._events):
            if drive is None or event.drive in (drive, None):
                found.append(event)
                if len(found) >= limit:
                    break
        return found

    async def history(self, query: EventQuery, limit: int = 200) -> list[GatewayEvent]:
        found = (event for event in reversed(self._events) if query.matches(event))
        return list(itertools.islice(found, limit))

    async def recorded_faults(self, drive: str, limit: int) -> list[dict[str, Any]]:
        return []

    def store_problem(self) -> str | None:
        return None


class Recorder(Protocol):
    """The gateway's persistent event store (`gateway.store.EventStore`), as far as used here."""

    def record(self, type: str, data: dict[str, Any], *, drive: str | None = None) -> None: ...

    async def recent_events(
        self,
        limit: int,
        drive: str | None = None,
        *,
        types: Sequence[str] = (),
        since: float | None = None,
        until: float | None = None,
    ) -> list[StoredEvent]: ...

    async def fault_history(self, drive: str, limit: int) -> list[FaultRecord]: ...

    def status(self) -> StoreStatus: ...


class ConsoleEventsRecorded(MemoryEventStore):
    """The console's events from the gateway's own store (`gateway.store`), which keeps them
    across restarts: faults, drives offline and online, ports, MQTT and console commands,
    Modbus-TCP writes by client and minute, reloads; and the faults with their snapshots.

    Each write made from the console is recorded there as a `command` event (published on
    `<base>/bridge/event` with the MQTT commands': the audit a plant keeps). The ring the class
    keeps besides is for the live pages' cheap synchronous reads."""

    def __init__(self, store: Recorder, size: int = MEMORY_EVENTS) -> None:
        super().__init__(size)
        self._store = store

    def record(self, event: GatewayEvent) -> None:
        super().record(event)
        if event.kind == "write" and (event.who or "").startswith("console"):
            data = {
                "drive": event.drive,
                "source": "console",
                "who": event.who,
                "what": event.text,
                "result": event.result,
                **_source(event),
            }
            self._store.record("command", data, drive=event.drive)
        elif event.kind in AUDIT_KINDS:
            data = _source(event)
            if event.kind == "config_changed":
                data["what"] = event.text
            self._store.record(event.kind, data)

    async def history(self, query: EventQuery, limit: int = 200) -> list[GatewayEvent]:
        found = await self._store.recent_events(
            limit, query.drive, types=query.types(), since=query.since, until=query.until
        )
        stored = [e for e in map(console_event, found) if query.matches(e)]
        merged = sorted([*stored, *await self._pending(query, limit)], key=_time, reverse=True)
        return merged[:limit]

    async def _pending(self, query: EventQuery, limit: int) -> list[GatewayEvent]:
        """Modbus-TCP writes reach the store summed up per client, drive and minute, once the
        minute is over: until then each one is shown from the ring (since this start) as it
        happened, and no longer once its minute's `modbus_writes` is stored (one row each)."""
        writes = [
            e
            for e in self._events
            if e.kind == "write" and (e.who or "").startswith("tcp:") and query.matches(e)
        ][-limit:]
        if not writes:
            return []
        since = writes[0].at - TALLY_SLACK_S
        tallies = await self._store.recent_events(
            MEMORY_EVENTS, types=("modbus_writes",), since=since - MINUTE_S
        )
        spans = [_tally_span(tally) for tally in tallies]
        return [
            replace(write, type="modbus_writes", pending=True)
            for write in reversed(writes)
            if not any(_covers(span, write) for span in spans)
        ]

    async def recorded_faults(self, drive: str, limit: int) -> list[dict[str, Any]]:
        return [fault.as_json() for fault in await self._store.fault_history(drive, limit)]

    def store_problem(self) -> str | None:
        return self._store.status().reason


TALLY_SLACK_S: Final = 1.0
"""A write is seen by the console's audit and counted in its tally a moment apart."""
MINUTE_S: Final = 60.0


def _time(event: GatewayEvent) -> float:
    return event.at


def _tally_span(tally: StoredEvent) -> tuple[str | None, str | None, float, float]:
    """(client host, drive, first write, last write) of a stored `modbus_writes`."""
    data = tally.data
    last = _epoch(data.get("to"), tally.time)
    return _text(data.get("client")), _text(data.get("drive")), tally.time, last


def _covers(span: tuple[str | None, str | None, float, float], write: GatewayEvent) -> bool:
    host, drive, first, last = span
    return (
        host == client_host(write.who or "")
        and drive == write.drive
        and first - TALLY_SLACK_S <= write.at <= last + TALLY_SLACK_S
    )


def _epoch(value: object, default: float) -> float:
    if not isinstance(value, str):
        return default
    try:
        return datetime.fromisoformat(value).timestamp()
    except ValueError:
        return default


def _source(event: GatewayEvent) -> dict[str, Any]:
    """An audit event's CR 2.8 fields beside its type, time and id (the store's)."""
    return {
        "category": event.category,
        "user": event.user,
        "address": event.address,
        "result": event.result,
    }


def audit_text(kind: str, data: dict[str, Any]) -> str:
    """A login, failed login or logout, a change of the configuration, in words."""
    user, address = data.get("user"), data.get("address")
    if kind == "config_changed":
        return str(data.get("what", "configuration changed"))
    return {
        "login": f"{user} logged in from {address}",
        "login_failed": f"failed login for {user!r} from {address}",
        "logout": f"{user} logged out from {address}",
    }[kind]


def console_event(event: StoredEvent) -> GatewayEvent:
    """A stored event as the console's pages show it: a kind and a line of words."""
    data = event.data
    kind, text = event.type, ""
    if kind in ("fault_raised", "fault_cleared"):
        text = str(data.get("fault_description") or data.get("fault_name") or "")
    elif kind in ("drive_offline", "drive_online"):
        text = "no answer: offline" if kind == "drive_offline" else "answering again"
    elif kind == "port_lost":
        text = f"port {data.get('port')} lost: {data.get('reason', '')}"
    elif kind == "port_back":
        text = f"port {data.get('port')} open again"
    elif kind == "command":
        what = data.get("what") or ", ".join(
            f"{key} {value}"
            for key, value in data.items()
            if key not in ("drive", "source", "who", "result", "transaction", "time")
        )
        kind, text = "write", str(what)
    elif kind == "modbus_writes":
        kind, text = "write", modbus_writes_text(data)
    elif kind in AUDIT_KINDS:
        text = audit_text(kind, data)
    elif kind == "config_reloaded":
        text = _reload_text(data)
    else:
        text = _in_words(data)
    drive = data.get("drive")
    who = data.get("who") or data.get("user") or data.get("source") or data.get("client")
    result = data.get("result")
    if event.type == "modbus_writes":
        refused = data.get("refused") or 0
        result = "ok" if not refused else f"{refused} refused"
    return GatewayEvent(
        kind,
        text,
        drive if isinstance(drive, str) else None,
        data.get("bus") if isinstance(data.get("bus"), str) else None,
        str(who) if who is not None else None,
        str(result) if result is not None else None,
        at=event.time,
        address=_text(data.get("address")),
        category=_text(data.get("category")),
        id=event.id,
        type=event.type,
    )


CSV_COLUMNS: Final = (
    *("id", "time", "kind", "type", "drive", "bus", "text"),
    *("who", "user", "address", "category", "result"),
)


def events_csv(events: Sequence[GatewayEvent]) -> str:
    """The events as a spreadsheet takes them: one row each, times in UTC (ISO 8601); text
    that a spreadsheet would run as a formula (a name typed at the login) quoted."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\r\n")
    writer.writerow(CSV_COLUMNS)
    for event in events:
        data = event.to_json()
        writer.writerow([cell(data[c]) for c in CSV_COLUMNS])
    return out.getvalue()


def modbus_writes_text(data: dict[str, Any]) -> str:
    """A minute's SCADA writes in words: "12 writes to unit 1 (function 06H, 10H; 2000H, 2001H)"."""
    writes = data.get("writes")
    count = f"{writes} write{'' if writes == 1 else 's'}"
    functions = ", ".join(f"{code}H" for code in data.get("functions") or ())
    registers = ", ".join(str(register) for register in data.get("registers") or ())
    what = "; ".join(
        part for part in (f"function {functions}" if functions else "", registers) if part
    )
    return f"{count} to unit {data.get('unit_id')}" + (f" ({what})" if what else "")


def _reload_text(data: dict[str, Any]) -> str:
    changed = ", ".join(map(str, data.get("changed") or ())) or "nothing"
    waiting = ", ".join(map(str, data.get("restart_needed") or ()))
    return f"configuration reloaded: {changed}" + (
        f"; after a restart: {waiting}" if waiting else ""
    )


def _in_words(data: dict[str, Any]) -> str:
    """An event of a type the console has no sentence for: its fields, not JSON."""
    return ", ".join(f"{key} {value}" for key, value in data.items() if key != "time")


def _text(value: object) -> str | None:
    return value if isinstance(value, str) else None
