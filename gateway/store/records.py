"""What the store keeps: events (each with its id and the time it happened) and faults."""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

from gateway.poller.drive_state import iso_time

Json = dict[str, Any]


class EventType(StrEnum):
    """The `type` of a `<base>/bridge/event` (a public interface: add, never rename)."""

    FAULT_RAISED = "fault_raised"
    FAULT_CLEARED = "fault_cleared"
    DRIVE_OFFLINE = "drive_offline"
    DRIVE_ONLINE = "drive_online"
    ALARM_RAISED = "alarm_raised"
    ALARM_CLEARED = "alarm_cleared"
    """A device file's point beyond its high or low limit, or back inside (the poller)."""
    PORT_LOST = "port_lost"
    PORT_BACK = "port_back"
    COMMAND = "command"
    MODBUS_WRITES = "modbus_writes"
    CONFIG_RELOADED = "config_reloaded"
    RETAINED_COMMAND_CLEARED = "retained_command_cleared"
    """A retained command was refused and removed from the broker (the MQTT bridge)."""
    LOGIN = "login"
    LOGIN_FAILED = "login_failed"
    """A wrong name or password, or an attempt refused while its name and address wait."""
    LOGOUT = "logout"
    CONFIG_CHANGED = "config_changed"
    """The configuration edited from the console: applied, rolled back, or refused (the audit)."""
    ROLE_CHANGED = "role_changed"
    """Redundancy: this gateway became standby, listening or active (`gateway.redundancy`)."""
    FOREIGN_MASTER = "foreign_master"
    """Redundancy: an active gateway heard another master's request and left the line."""
    ANOTHER_MASTER_HEARD = "another_master_heard"
    """Redundancy: a box asked active heard another master for a while (a cut between the
    boxes): it gives the virtual address up (its fault file says 1)."""
    ANOTHER_MASTER_GONE = "another_master_gone"
    """Redundancy: that box heard no other master for `silence_ms`: fit again."""
    PEER_CONFIG_DIFFERS = "peer_config_differs"
    """Redundancy: the other box runs another configuration in what both must share (its keys)."""
    PEER_CONFIG_ALIKE = "peer_config_alike"
    """Redundancy: the other box runs this box's configuration again."""


@dataclass(frozen=True, slots=True)
class NewEvent:
    """An event on its way into the store's file."""

    type: str
    time: float
    """Wall-clock time (epoch seconds) it happened: kept through outages and restarts."""
    data: Json
    drive: str | None = None
    snapshot: Json | None = None
    """For a raised fault: the drive's running values at that moment (its fault history)."""
    id: int = 0
    """Given by the store when the event is recorded: the same from memory and from the file."""
    settles: str | None = None
    """The key of the tally this event completes: its row goes in the event's transaction."""

    def stored(self) -> StoredEvent:
        """As the broker gets it (from memory, before the file has it)."""
        return StoredEvent(self.id, self.type, self.time, self.data)


@dataclass(frozen=True, slots=True)
class HistoryPoint:
    """One drive's polled values over one history step (`gateway.store.history`)."""

    drive: str
    time: float
    """The step's start (epoch seconds)."""
    values: dict[str, float | str]


@dataclass(frozen=True, slots=True)
class ConfigVersion:
    """A configuration as it was applied from the console (or found before the first edit)."""

    id: int
    time: float
    user: str
    text: str
    note: str

    def summary(self) -> Json:
        return {"id": self.id, "time": iso_time(self.time), "user": self.user, "note": self.note}


@dataclass(frozen=True, slots=True)
class StoredEvent:
    id: int
    """Strictly increasing, across restarts too: consumers de-duplicate by it."""
    type: str
    time: float
    data: Json = field(default_factory=dict)

    def payload(self) -> Json:
        """What `<base>/bridge/event` carries."""
        return {"id": self.id, "type": self.type, "time": iso_time(self.time), "data": self.data}


@dataclass(frozen=True, slots=True)
class FaultRecord:
    """One fault of one drive: when it came, when it went, what the drive was doing."""

    drive: str
    code: int
    name: str
    description: str
    raised: float
    cleared: float | None
    snapshot: Json

    def as_json(self) -> Json:
        return {
            "code": self.code,
            "name": self.name,
            "description": self.description,
            "raised": iso_time(self.raised),
            "cleared": None if self.cleared is None else iso_time(self.cleared),
            "duration_s": None if self.cleared is None else round(self.cleared - self.raised, 3),
            "snapshot": self.snapshot,
        }
