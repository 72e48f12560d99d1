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

import json
import time
from collections import deque
from dataclasses import asdict, dataclass, field
from enum import StrEnum
from typing import Any, Final, Protocol

from gateway.poller.drive_state import iso_time
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

    def to_json(self) -> dict[str, Any]:
        data = asdict(self)
        data["time"] = iso_time(self.at)
        return data


class EventStore(Protocol):
    def record(self, event: GatewayEvent) -> None:
        """Keep `event`; must return at once (called on the event loop)."""

    def recent(self, drive: str | None = None, limit: int = 200) -> list[GatewayEvent]:
        """The newest first; only `drive`'s (and the line-wide ones of no drive) when given."""

    async def history(self, drive: str | None = None, limit: int = 200) -> list[GatewayEvent]:
        """As `recent`, from wherever the events are kept longest (across restarts, if kept)."""

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

    async def history(self, drive: str | None = None, limit: int = 200) -> list[GatewayEvent]:
        return self.recent(drive, limit)

    async def recorded_faults(self, drive: str, limit: int) -> list[dict[str, Any]]:
        return []

    def store_problem(self) -> str | None:
        return None


class Recorder(Protocol):
    """The gateway's persistent event store (`gateway.store.EventStore`), as far as used here."""

    def record(self, type: str, data: dict[str, Any], *, drive: str | None = None) -> None: ...

    async def recent_events(self, limit: int, drive: str | None = None) -> list[StoredEvent]: ...

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
            self._store.record(event.kind, _source(event))

    async def history(self, drive: str | None = None, limit: int = 200) -> list[GatewayEvent]:
        stored = [console_event(event) for event in await self._store.recent_events(limit, drive)]
        # Modbus-TCP writes reach the store summed up per client, unit and minute; the audit
        # line of each one, as it happened, is the ring's (since this start).
        each_write = [e for e in self.recent(drive, limit) if (e.who or "").startswith("tcp:")]
        merged = sorted([*stored, *each_write], key=lambda event: event.at, reverse=True)
        return merged[:limit]

    async def recorded_faults(self, drive: str, limit: int) -> list[dict[str, Any]]:
        return [fault.as_json() for fault in await self._store.fault_history(drive, limit)]

    def store_problem(self) -> str | None:
        return self._store.status().reason


def _source(event: GatewayEvent) -> dict[str, Any]:
    """An audit event's CR 2.8 fields beside its type, time and id (the store's)."""
    user = event.who.removeprefix("console:") if event.who else None
    return {
        "category": event.category,
        "user": user,
        "address": event.address,
        "result": event.result,
    }


def audit_text(kind: str, data: dict[str, Any]) -> str:
    """A login, failed login or logout in words."""
    user, address = data.get("user"), data.get("address")
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
        kind, text = "write", f"Modbus-TCP writes: {json.dumps(data, sort_keys=True)}"
    elif kind in AUDIT_KINDS:
        text = audit_text(kind, data)
    else:
        text = json.dumps(data, sort_keys=True)
    drive = data.get("drive")
    who = data.get("who") or data.get("user") or data.get("source") or data.get("client")
    result = data.get("result")
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
    )


def _text(value: object) -> str | None:
    return value if isinstance(value, str) else None
