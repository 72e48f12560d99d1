"""Writes and method calls from OPC UA clients, carried to the drives by MQTT's command path.

Each is a `/set` payload handed to `Commands.set` (`gateway.mqtt.commands`), whose source is
`opcua`: the same parsing and checks (the model's ranges and steps, the set-point's limit, RAM
writes), the same Modbus path at write priority, the same `command` event. Before it, what is
OPC UA's own: the user's role (an operator or an admin) and `opcua.commands_enabled`.

The answer is the MQTT acknowledgement's word, as a StatusCode (`STATUS_OF`) and, for a
method, as its output argument `Answer` ("ok", or the word and the reason):

    a set-point variable written      {"frequency_hz": value}
    a device file's writable point    {"point": key, "value": value}
    a parameter node written          {"parameter": "P00.11", "value": value}
    a method RunForward, Stop...      {"command": "run_forward"}

asyncua carries a Write request through its attribute service; `CommandWrites` takes the
writes to the nodes above out of it and hands every other on unchanged.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping
from contextvars import ContextVar
from dataclasses import dataclass
from typing import Any, Final, cast

from asyncua import ua
from asyncua.server.address_space import AddressSpace, AttributeService

from gateway.mqtt.commands import CommandDrive, Commands
from gateway.mqtt.requests import Json
from gateway.opcua.logins import Login
from gateway.store import EventStore, EventType

log = logging.getLogger(__name__)

STATUS_OF: Final[Mapping[str, int]] = {
    "ok": ua.StatusCodes.Good,
    "commands_disabled": ua.StatusCodes.BadUserAccessDenied,
    "not_allowed": ua.StatusCodes.BadUserAccessDenied,
    "invalid_request": ua.StatusCodes.BadInvalidArgument,
    "invalid_value": ua.StatusCodes.BadOutOfRange,
    "offline": ua.StatusCodes.BadCommunicationError,
    "unavailable": ua.StatusCodes.BadCommunicationError,
    "timeout": ua.StatusCodes.BadTimeout,
    "busy": ua.StatusCodes.BadTooManyOperations,
}
"""The command path's answer words as StatusCodes; a drive's own exception (its profile's word)
is BadDeviceFailure, its 03H (a value it refuses) BadOutOfRange."""
ILLEGAL_DATA_VALUE: Final = 3
WHO: ContextVar[str | None] = ContextVar("opcua_who", default=None)
"""The OPC UA user whose write or call is being carried out (`CommandPath.carry`)."""


class AuditedEvents:
    """The store as the command path records into it: each `command` event of an OPC UA write
    or call names its user (`"user"`, as the console's own audit events do), beside its
    `"source": "opcua"`. The MQTT path's events are the same without it: a broker's client
    has no user of the gateway's."""

    def __init__(self, events: EventStore) -> None:
        self.events = events

    def record(self, type: str, data: Json, **where: Any) -> None:
        who = WHO.get()
        if who is not None and type == EventType.COMMAND:
            data = {**data, "user": who}
        self.events.record(type, data, **where)

    def as_store(self) -> EventStore:
        """For `Commands`, which records through `record` only."""
        return cast(EventStore, self)


@dataclass(frozen=True, slots=True)
class Answer:
    status: int
    words: str
    """"ok", or the answer's word and its message."""


@dataclass(frozen=True, slots=True)
class WriteTarget:
    """A variable whose writes go to a drive: the payload key its value goes under."""

    drive: CommandDrive
    key: str
    shape: str
    """`point`: a device file's point (`{"point": key, "value": v}`); `parameter`: a parameter
    (`{"parameter": key, "value": v}`); `setpoint`: the set frequency."""

    def payload(self, value: object) -> Json:
        if self.shape == "setpoint":
            return {"frequency_hz": value}
        return {self.shape: self.key, "value": value}


class CommandPath:
    """Who may, then `Commands.set`; the answer as an OPC UA status and words."""

    def __init__(self, commands: Commands, enabled: bool) -> None:
        self.commands = commands
        self.enabled = enabled

    async def carry(self, drive: CommandDrive, payload: Json, who: Login | None) -> Answer:
        name = who.shown if who is not None else "nobody"
        if who is None or not who.may_command:
            return self._refused(drive, payload, name, "not_allowed", "a viewer may not write")
        if not self.enabled:
            reason = "this gateway's OPC UA server is monitoring only (commands_enabled: false)"
            return self._refused(drive, payload, name, "commands_disabled", reason)
        said = WHO.set(name)
        try:
            with self.commands.acknowledgement() as acknowledgement:
                acknowledgement.ok(await self.commands.set(drive, payload))
        finally:
            WHO.reset(said)
        response = acknowledgement.response
        log.info("OPC UA: %s asked %s of %s: %s", name, payload, drive.name, response["status"])
        if response["status"] == "ok":
            return Answer(ua.StatusCodes.Good, "ok")
        return Answer(status_of(response), f"{response['error']}: {response['message']}")

    def _refused(self, drive: CommandDrive, payload: Json, who: str, word: str, why: str) -> Answer:
        log.warning("OPC UA: refused %s to %s on %s: %s", payload, who, drive.name, why)
        return Answer(STATUS_OF[word], f"{word}: {why}")


def status_of(response: Json) -> int:
    """The StatusCode of a refusal's or an exception's answer (`error`, `exception_code`)."""
    word = response["error"]
    if word in STATUS_OF:
        return STATUS_OF[word]
    if response.get("exception_code") == ILLEGAL_DATA_VALUE:
        return int(ua.StatusCodes.BadOutOfRange)
    return int(ua.StatusCodes.BadDeviceFailure)


class CommandWrites(AttributeService):  # type: ignore[misc]  # asyncua read as untyped
    """asyncua's attribute service, with the writes of `targets`' Values carried to the drives."""

    def __init__(
        self,
        aspace: AddressSpace,
        targets: Mapping[ua.NodeId, WriteTarget],
        path: CommandPath,
        written: Callable[[ua.NodeId], None],
    ) -> None:
        super().__init__(aspace)
        self.targets = targets
        self.path = path
        self.written = written
        """Told of each target written Good (a parameter: read again at the next Read)."""

    async def write(self, params: ua.WriteParameters, user: Any = None) -> list[ua.StatusCode]:
        results: list[ua.StatusCode] = []
        for item in params.NodesToWrite:
            target = self.targets.get(item.NodeId)
            if target is None or item.AttributeId != ua.AttributeIds.Value:
                single = ua.WriteParameters(NodesToWrite=[item])
                results += (
                    await super().write(single, user) if user else await super().write(single)
                )
                continue
            value = item.Value.Value.Value if item.Value and item.Value.Value else None
            who = user if isinstance(user, Login) else None
            answer = await self.path.carry(target.drive, target.payload(value), who)
            if answer.status == ua.StatusCodes.Good:
                self.written(item.NodeId)
            results.append(ua.StatusCode(answer.status))
        return results
