"""The kinds of message the bridge takes, each knowing its lane, how to run it and answer it.

| topic                                  | kind            | lane                           |
|----------------------------------------|-----------------|--------------------------------|
| <base>/<drive>/set                     | DriveCommand    | the drive's                    |
| <base>/<other>/set (no such drive)     | UnknownDrive    | "unknown": answered at once    |
| <base>/<drive>/get                     | DriveRefresh    | the drive's refreshes          |
| <base>/bridge/request/<op>             | BRIDGE_REQUESTS | the named drive's, or "bridge" |
| <base>/bridge/request/fault_history    | FaultHistory    | "store" (never waits on a line)|
| <discovery_prefix>/status              | DiscoveryAsked  | "discovery"                    |
| <base>/bridge/info                     | GatewayInfo     | none: checked at once          |

A new `bridge/request/<op>` is one class here, derived from `BridgeRequest` and listed in
`BRIDGE_REQUESTS`: its topic, subscription, lane, safety checks and answer come with it. What a
command means in registers is the profile's (`gateway.profile.commands`), its payload's shape
`gateway.mqtt.requests`'.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import ClassVar, Final

import aiomqtt

from gateway.errors import CommandRefused
from gateway.mqtt.commands import CommandDrive, Commands
from gateway.mqtt.dispatcher import CommandKind, Incoming
from gateway.mqtt.lanes import Lanes
from gateway.mqtt.publisher import Publisher
from gateway.mqtt.requests import (
    BRIDGE_READ_KEYS,
    BRIDGE_WRITE_KEYS,
    COMMON_KEYS,
    Json,
    check_keys,
    parse_object,
    parse_read,
    parse_write,
)
from gateway.mqtt.stats import BridgeStats
from gateway.mqtt.topics import Topics
from gateway.poller import Poller
from gateway.store import EventStore

log = logging.getLogger(__name__)

BRIDGE_LANE: Final = "bridge"


@dataclass(slots=True)
class Context:
    """What the kinds share: the parts they use, and where the gateway stands on the broker."""

    topics: Topics
    commands: Commands
    publisher: Publisher
    poller: Poller
    lanes: Lanes
    stats: BridgeStats
    gateway_id: str
    discovery_prefix: str
    events: EventStore
    other_gateways: set[str] = field(default_factory=set)


def drive_lane(drive: str) -> str:
    """Commands to one drive run in the order they came, a bridge request about it too."""
    return f"drive:{drive}"


class DriveCommand:
    command = True
    """`<base>/<drive>/set`: a control command, a set-point, or a parameter write."""

    def __init__(self, context: Context, drive: CommandDrive) -> None:
        self.context = context
        self.drive = drive
        self.response_topic = context.topics.set_response(drive.name)

    def lane(self, message: Incoming) -> str | None:
        self.context.stats.commands_received += 1
        return drive_lane(self.drive.name)

    async def run(self, client: aiomqtt.Client, message: Incoming) -> None:
        commands = self.context.commands
        with commands.acknowledgement() as answer:
            payload = commands.admit(message, answer, writes=True)
            answer.ok(await commands.set(self.drive, payload))
        await self.context.publisher.respond(client, self.response_topic, answer.response)


UNKNOWN_LANE: Final = "unknown"


class UnknownDrive:
    command = True
    """`<base>/<name>/set` for a name that is no drive of this gateway: answered
    `unknown_drive` on its `/set/response`, as any other refusal is (a misspelt drive would
    otherwise hear nothing until its own timeout)."""

    def __init__(self, context: Context, name: str) -> None:
        self.context = context
        self.name = name
        self.response_topic = context.topics.set_response(name)

    def lane(self, message: Incoming) -> str | None:
        self.context.stats.commands_received += 1
        return UNKNOWN_LANE

    async def run(self, client: aiomqtt.Client, message: Incoming) -> None:
        commands = self.context.commands
        with commands.acknowledgement() as answer:
            commands.admit(message, answer, writes=False)  # a retained or stale one says so
            known = ", ".join(sorted(commands.drives))
            raise CommandRefused("unknown_drive", f"no drive {self.name!r} here (drives: {known})")
        await self.context.publisher.respond(client, self.response_topic, answer.response)


class AnySet:
    """`<base>/+/set`, subscribed to in place of each drive's own: a drive's `/set` goes to
    its `DriveCommand` (an exact topic), any other name's to an `UnknownDrive`."""

    def __init__(self, context: Context) -> None:
        self.context = context
        self.filter = context.topics.set("+")

    def covers(self, topic: str) -> bool:
        name = self.context.topics.drive_of(topic)
        return name is not None and topic == self.context.topics.set(name)

    def kind(self, topic: str) -> CommandKind | None:
        if not self.covers(topic):
            return None
        name = self.context.topics.drive_of(topic)
        assert name is not None
        return UnknownDrive(self.context, name)


class DriveRefresh:
    command = True
    """`<base>/<drive>/get`: poll the drive now and publish its state (no answer of its own)."""

    response_topic = None

    def __init__(self, context: Context, drive: str) -> None:
        self.context = context
        self.drive = drive

    def lane(self, message: Incoming) -> str | None:
        lane = f"get:{self.drive}"
        if self.context.lanes.waiting(lane):
            self.context.stats.ignored += 1  # the refresh already waiting publishes the same
            return None
        return lane

    async def run(self, client: aiomqtt.Client, message: Incoming) -> None:
        context = self.context
        if context.commands.may_refresh(self.drive, message):
            await context.poller.refresh(self.drive)
            telemetry = context.poller.telemetry(self.drive)
            await context.publisher.state(client, self.drive, telemetry, force=True)


class BridgeRequest:
    command = True
    """`<base>/bridge/request/<operation>`, answered on `<base>/bridge/response/<operation>`."""

    operation: ClassVar[str]
    writes: ClassVar[bool]
    """A request that changes the drive: refused with `commands_enabled: false`."""

    def __init__(self, context: Context) -> None:
        self.context = context
        self.response_topic = context.topics.bridge_response(self.operation)

    def lane(self, message: Incoming) -> str | None:
        try:
            drive = parse_object(message.payload).get("drive")
        except CommandRefused:
            return BRIDGE_LANE  # answered at once: invalid_request
        if isinstance(drive, str) and drive in self.context.commands.drives:
            return drive_lane(drive)
        return BRIDGE_LANE

    async def run(self, client: aiomqtt.Client, message: Incoming) -> None:
        commands = self.context.commands
        with commands.acknowledgement() as answer:
            payload = commands.admit(message, answer, writes=self.writes)
            answer.ok(await self.execute(payload))
        await self.context.publisher.respond(client, self.response_topic, answer.response)

    async def execute(self, payload: Json) -> Json:
        """The request's `data` once done; raises CommandRefused or a ModbusError."""
        raise NotImplementedError


class ReadParameter(BridgeRequest):
    """`{"drive": "pump1", "parameter": "P07.27", "count": 6}`; a read changes nothing on the
    drive: monitoring-only gateways still answer it."""

    operation = "read_parameter"
    writes = False

    async def execute(self, payload: Json) -> Json:
        check_keys(payload, BRIDGE_READ_KEYS)
        drive = self.context.commands.drive_named(payload)
        read = parse_read(payload, drive.read_limit, drive.profile)
        words = await self.context.commands.read(drive, read)
        return {"drive": drive.name, **read.echo, **read.result(words)}


class WriteParameter(BridgeRequest):
    """`{"drive": "pump1", "parameter": "P00.11", "value": 10.0}`."""

    operation = "write_parameter"
    writes = True

    def lane(self, message: Incoming) -> str | None:
        self.context.stats.commands_received += 1
        return super().lane(message)

    async def execute(self, payload: Json) -> Json:
        check_keys(payload, BRIDGE_WRITE_KEYS)
        drive = self.context.commands.drive_named(payload)
        write = parse_write(payload, drive.profile)
        await self.context.commands.write(drive, write)
        return {"drive": drive.name, **write.echo}


class FaultHistory(BridgeRequest):
    """`{"drive": "pump1", "limit": 20}`: the drive's faults kept in the store, newest first,
    each with its raise and clear time and the running values when it was raised."""

    operation = "fault_history"
    writes = False
    DEFAULT_LIMIT: ClassVar[int] = 20
    MAX_LIMIT: ClassVar[int] = 1000

    def lane(self, message: Incoming) -> str | None:
        return "store"  # a read of the store: never behind a drive's commands on its line

    async def execute(self, payload: Json) -> Json:
        check_keys(payload, COMMON_KEYS | {"drive", "limit"})
        drive = self.context.commands.drive_named(payload)
        limit = payload.get("limit", self.DEFAULT_LIMIT)
        if (
            isinstance(limit, bool)
            or not isinstance(limit, int)
            or not 1 <= limit <= self.MAX_LIMIT
        ):
            raise CommandRefused("invalid_request", "limit must be a whole number 1..1000")
        faults = await self.context.events.fault_history(drive.name, limit)
        return {"drive": drive.name, "faults": [fault.as_json() for fault in faults]}


BRIDGE_REQUESTS: Final[tuple[type[BridgeRequest], ...]] = (
    ReadParameter,
    WriteParameter,
    FaultHistory,
)
"""Every `bridge/request/<op>` the gateway answers."""


class DiscoveryAsked:
    command = False  # Home Assistant's retained "online" is how it is meant to be
    """Home Assistant came (back) online: it wants the discovery messages again."""

    response_topic = None

    def __init__(self, context: Context) -> None:
        self.context = context

    def lane(self, message: Incoming) -> str | None:
        if message.payload.strip() != b"online" or self.context.lanes.waiting("discovery"):
            return None
        return "discovery"

    async def run(self, client: aiomqtt.Client, message: Incoming) -> None:
        await self.context.publisher.discovery(client)


class GatewayInfo:
    command = False
    """Our own `bridge/info`: another gateway publishing it would overwrite our retained state.

    Each gateway publishes its info before it subscribes, so two that connect at the same moment
    can both publish first: only the later one's info stays retained, and that one never hears
    of the other. So a gateway that finds a new one answers once with its own info again: the
    other, subscribed by now, hears it live and reports the conflict too (once per gateway
    found, so two of them don't answer each other for ever).
    """

    response_topic = None

    def __init__(self, context: Context) -> None:
        self.context = context

    def lane(self, message: Incoming) -> str | None:
        if not self._found_another(message.payload):
            return None
        return "info"

    async def run(self, client: aiomqtt.Client, message: Incoming) -> None:
        await self.context.publisher.info(client)

    def _found_another(self, payload: bytes) -> bool:
        """Counts and reports another gateway's info; True the first time that gateway is seen."""
        context = self.context
        try:
            other = json.loads(payload).get("gateway_id")
        except (ValueError, AttributeError):
            return False
        if not isinstance(other, str) or other == context.gateway_id:
            return False
        context.stats.conflicts += 1
        if other in context.other_gateways:
            return False
        context.other_gateways.add(other)
        log.error(
            "MQTT: gateway %r also publishes under %r: give each gateway its own base_topic",
            other,
            context.topics.base,
        )
        return True


def command_kinds(
    context: Context, drives: Mapping[str, CommandDrive], discovery: bool
) -> dict[str, CommandKind]:
    """Topic → kind, for every topic the bridge subscribes to."""
    topics = context.topics
    kinds: dict[str, CommandKind] = {}
    for name, drive in drives.items():
        kinds[topics.set(name)] = DriveCommand(context, drive)
    for name in drives:
        kinds[topics.get(name)] = DriveRefresh(context, name)
    kinds[topics.bridge_info] = GatewayInfo(context)
    for request in BRIDGE_REQUESTS:
        kinds[topics.bridge_request(request.operation)] = request(context)
    if discovery:
        kinds[f"{context.discovery_prefix}/status"] = DiscoveryAsked(context)
    return kinds
