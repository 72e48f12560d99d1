"""The gateway's own events as the console shows them: faults raised and cleared, drives offline
and online, ports lost and back, and writes (an audit line: who, what, when, result).

The console reads and writes them only through `EventStore`, a small interface: today an
in-memory ring (`MemoryEventStore`, bounded, lost at restart); a store that survives restarts
(the "Nothing lost" issue) plugs in by implementing the same two methods.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import asdict, dataclass, field
from typing import Any, Protocol

from gateway.poller.drive_state import iso_time

MEMORY_EVENTS = 2000


@dataclass(frozen=True, slots=True)
class GatewayEvent:
    kind: str
    """fault_raised, fault_cleared, drive_offline, drive_online, port_lost, port_back, write."""
    text: str
    """In words: "OL1: inverter overload", "control word = 1 (run_forward) → ok"."""
    drive: str | None = None
    bus: str | None = None
    who: str | None = None
    """For writes: "console:alice", "tcp:10.0.0.5:40112", "mqtt"."""
    result: str | None = None
    at: float = field(default_factory=time.time)

    def to_json(self) -> dict[str, Any]:
        data = asdict(self)
        data["time"] = iso_time(self.at)
        return data


class EventStore(Protocol):
    def record(self, event: GatewayEvent) -> None:
        """Keep `event`; must return at once (called on the event loop)."""

    def recent(self, drive: str | None = None, limit: int = 200) -> list[GatewayEvent]:
        """The newest first; only `drive`'s (and the line-wide ones of no drive) when given."""


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


class Recorder(Protocol):
    """The gateway's persistent event store (`gateway.store.EventStore`), as far as used here."""

    def record(self, type: str, data: dict[str, Any], *, drive: str | None = None) -> None: ...


class ConsoleEventsRecorded(MemoryEventStore):
    """The console's ring of events, with each write made from the console also recorded in the
    gateway's own store as a `command` event: published on `<base>/bridge/event` and kept across
    restarts with the MQTT commands', the audit a plant keeps. (The rest the store records itself,
    from the poller and the buses.)"""

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
            }
            self._store.record("command", data, drive=event.drive)
