"""Commands from MQTT carried to the drives, each answered with an acknowledgement.

The checks that keep a plant safe come first, before anything reaches the bus: a retained command
is never executed (it would run again at every reconnect of every subscriber), a stale one neither
(it waited somewhere while the situation changed: its `time` is old, or it waited in the gateway
longer than `command_max_age_s` since it was received), and none at all with
`commands_enabled: false`.
Writes then go through the router at write priority, as a SCADA write would; the drive's own
exception comes back by its profile's name (an INVT drive's 04H `operation_failure`, another
maker's `server_device_failure`), the gateway's as its reason.
Each drive is resolved to its route once, when the bridge is built: a command names a drive and
goes straight to its route.
"""

from __future__ import annotations

import asyncio
import logging
import struct
import time
from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Final, Protocol

from gateway.errors import (
    CommandRefused,
    DriveException,
    DriveOffline,
    GatewayPathUnavailable,
    GatewayTargetFailed,
    ModbusError,
    QueueFull,
)
from gateway.logs import repeated
from gateway.modbus.functions import is_exception
from gateway.mqtt.dispatcher import Incoming
from gateway.mqtt.requests import (
    Json,
    RegisterRead,
    RegisterWrite,
    check_age,
    check_waited,
    error_response,
    ok_response,
    parse_object,
    parse_set,
    transaction_of,
)
from gateway.poller import Poller
from gateway.profile import STANDARD_EXCEPTIONS, DriveProfile
from gateway.profile.points import for_series
from gateway.routing import MAX_READ_WORDS, Route, Router
from gateway.setpoint_limit import setpoint_refusal
from gateway.store import EventStore, EventType

log = logging.getLogger(__name__)

MQTT_CLIENT: Final = "mqtt"
"""The bus's name for requests from MQTT (its own round-robin share, like one SCADA client)."""


@dataclass(frozen=True, slots=True)
class CommandDrive:
    """A drive as commands reach it: its route and its profile."""

    name: str
    route: Route
    profile: DriveProfile

    @property
    def read_limit(self) -> int:
        # When the router splits reads for this drive (on by default for INVT models), one
        # message may ask for what one Modbus read can carry; otherwise the drive's own limit.
        return MAX_READ_WORDS if self.route.max_words is not None else self.profile.max_words


class CommandRules(Protocol):
    """What the command path reads of its source's settings (MQTT's, or the OPC UA server's)."""

    @property
    def commands_enabled(self) -> bool: ...

    @property
    def command_max_age_s(self) -> float: ...


class Commands:
    def __init__(
        self,
        settings: CommandRules,
        router: Router,
        poller: Poller,
        drives: Mapping[str, CommandDrive],
        events: EventStore,
        source: str = "mqtt",
        client: str = MQTT_CLIENT,
    ) -> None:
        """`source`: what a `command` event names as where the command came from (the JSON
        topics' `mqtt`, Sparkplug's `sparkplug`, the OPC UA server's `opcua`). `client`: who
        asked, as the bus's traffic monitor and request metrics name it (`mqtt` for both MQTT
        sources, as ever; `opcua`)."""
        self.settings = settings
        self.source = source
        self.client = client
        self.router = router
        self.poller = poller
        self.drives = drives
        self.statuses: Counter[str] = Counter()
        """Commands answered, by status: ok, or the error (a fixed set of names)."""
        self.events = events
        self.executed = 0
        self.refused = 0

    # `received_at` of each message is the monotonic time the bridge received it: what waited
    # longer than `command_max_age_s` before its turn came is refused, not run late.

    def acknowledgement(self) -> Acknowledgement:
        """The answer to one message, built as it is checked and carried out:

            with commands.acknowledgement() as answer:
                payload = commands.admit(message, answer, writes=True)
                answer.ok(await commands.set(drive, payload))
            respond(answer.response)

        A refusal or a Modbus exception raised inside the block becomes the answer."""
        return Acknowledgement(self)

    def admit(self, message: Incoming, answer: Acknowledgement, writes: bool) -> Json:
        """The message's payload, once the checks that keep a plant safe passed (see the
        module's docstring); raises CommandRefused. `writes`: it would change a drive."""
        payload = parse_object(message.payload)
        answer.transaction = transaction_of(payload)
        self._check_allowed(payload, message.retained, writes)
        check_waited(message.received_at, self.settings.command_max_age_s, time.monotonic())
        return payload

    def _count(self, status: str) -> None:
        if status == "ok":
            self.executed += 1
        else:
            self.refused += 1
        self.statuses[status] += 1

    def may_refresh(self, drive: str, message: Incoming) -> bool:
        """`<base>/<drive>/get`: False (and logged) when the request is to be ignored."""
        if message.retained:
            log.warning("ignored a retained message on %s/get", drive)
            return False
        try:
            check_waited(message.received_at, self.settings.command_max_age_s, time.monotonic())
        except CommandRefused as exc:
            log.info("MQTT %s/get ignored: %s", drive, exc)
            return False
        return True

    def drive_named(self, payload: Json) -> CommandDrive:
        """The drive a bridge request names in its `drive` key."""
        name = payload.get("drive")
        drive = self.drives.get(name) if isinstance(name, str) else None
        if drive is None:
            known = ", ".join(sorted(self.drives))
            raise CommandRefused("unknown_drive", f"drive must be one of: {known}")
        return drive

    async def set(self, drive: CommandDrive, payload: Json) -> Json:
        """A `/set` payload carried out (a command, set-point, parameter or point write); what
        the acknowledgement repeats of it. Raises CommandRefused or a ModbusError."""
        write = parse_set(payload, drive.profile)
        try:
            await self.write(drive, write)
        except DriveException as exc:
            note = borrowed_note(drive.profile, write.echo.get("parameter"))
            if note:
                raise DriveException(exc.function, exc.code, f"{exc}; {note}", exc.name) from None
            polled = self.poller.drives.get(drive.name)
            if "frequency_hz" not in write.echo or polled is None:
                raise
            message = await setpoint_refusal(
                self.router,
                polled.settings,
                float(write.echo["frequency_hz"]),
                exc.code,
                self.poller.max_frequency_hz,
            )
            raise DriveException(exc.function, exc.code, message, exc.name) from None
        return write.echo

    async def write(self, drive: CommandDrive, write: RegisterWrite) -> None:
        """Carry a command or parameter write to the drive; a `command` event says what came of
        it (who changed what on a drive, and when, is what a plant asks after an incident)."""
        try:
            for pdu, pause_s in write.steps:
                await self._execute(drive, pdu)
                if pause_s:
                    await asyncio.sleep(pause_s)
        except ModbusError as exc:
            error, code = modbus_error(exc)
            outcome: Json = {"result": error, "exception_code": code}
            if isinstance(exc, GatewayTargetFailed) and exc.sent_unconfirmed:
                # No reply confirmed it, but it went out: the drive may have carried it out.
                outcome |= {"may_have_run": True, "times_sent": exc.sent_unconfirmed}
            self._record(drive, write, outcome)
            raise
        self._record(drive, write, {"result": "ok"})
        log.info("MQTT command to %s done: %s", drive.name, write.echo)
        self.poller.poll_now(drive.name)  # its new state out at once, not at the next interval

    async def read(self, drive: CommandDrive, read: RegisterRead) -> list[int]:
        reply = await self._execute(drive, read.pdu)
        return list(struct.unpack(f">{read.count}H", reply[2 : 2 + 2 * read.count]))

    def _record(self, drive: CommandDrive, write: RegisterWrite, outcome: Json) -> None:
        data = {"drive": drive.name, "source": self.source, **write.echo, **outcome}
        self.events.record(EventType.COMMAND, data, drive=drive.name)

    def _check_allowed(self, payload: Json, retained: bool, writes: bool) -> None:
        if retained:
            raise CommandRefused(
                "retained", "a retained command is never executed: publish without retain"
            )
        if writes and not self.settings.commands_enabled:
            raise CommandRefused(
                "commands_disabled", "this gateway is monitoring only (commands_enabled: false)"
            )
        check_age(payload, self.settings.command_max_age_s, time.time())

    async def _execute(self, drive: CommandDrive, pdu: bytes) -> bytes:
        # The router's route of the moment: a reload may have reopened the drive's bus.
        route = self.router.route_for_drive(drive.name)
        reply = await self.router.request(route, pdu, client=self.client)
        if is_exception(reply):
            code = reply[1] if len(reply) > 1 else 0
            words = drive.profile.exceptions
            raise DriveException(pdu[0], code, words.describe(code), words.name(code))
        return reply


def borrowed_note(profile: DriveProfile, spelled: object) -> str:
    """`Point.borrowed_note` of the parameter a write named (P01.00, 0100H), "" for another."""
    if not isinstance(spelled, str):
        return ""
    try:
        return for_series(profile.resolve(spelled), profile).borrowed_note
    except ValueError:
        return ""


class Acknowledgement:
    """The answer to one command message (`Commands.acknowledgement`): ok with the data the
    command gave, or why not (the refusal's reason, or the Modbus exception's name), each
    counted by status."""

    def __init__(self, commands: Commands) -> None:
        self.commands = commands
        self.transaction: Any = None
        """The caller's `transaction`, repeated in the answer (once the payload parsed)."""
        self.response: Json = {}

    def __enter__(self) -> Acknowledgement:
        return self

    def ok(self, data: Json) -> None:
        self.commands._count("ok")
        self.response = ok_response(self.transaction, data)

    def __exit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: object
    ) -> bool:
        """A refusal or a Modbus exception: answered, not raised further. Anything else (a
        bug, a cancellation) goes on up."""
        if isinstance(exc, CommandRefused):
            log.warning(
                "MQTT command refused (%s): %s",
                exc.reason,
                exc,
                extra=repeated(f"mqtt-refused-{exc.reason}"),  # anyone may send them, often
            )
            self.commands._count(exc.reason)
            self.response = error_response(self.transaction, exc.reason, str(exc))
            return True
        if isinstance(exc, ModbusError):
            error, code = modbus_error(exc)
            self.commands._count(error)
            self.response = error_response(self.transaction, error, str(exc), code)
            return True
        return False


def modbus_error(exc: ModbusError) -> tuple[str, int]:
    """The response's `error` and `exception_code` for a Modbus exception, drive's or gateway's."""
    if isinstance(exc, DriveException):
        return exc.name or STANDARD_EXCEPTIONS.name(exc.code), exc.code
    if isinstance(exc, DriveOffline):
        return "offline", exc.code
    if isinstance(exc, GatewayTargetFailed):
        return "timeout", exc.code
    if isinstance(exc, QueueFull):
        return "busy", exc.code
    if isinstance(exc, GatewayPathUnavailable):
        return "unavailable", exc.code
    return STANDARD_EXCEPTIONS.name(exc.code), exc.code
