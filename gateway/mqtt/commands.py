"""Commands from MQTT carried to the drives, each answered with an acknowledgement.

The checks that keep a plant safe come first, before anything reaches the bus: a retained command
is never executed (it would run again at every reconnect of every subscriber), a stale one neither
(it waited somewhere while the situation changed: its `time` is old, or it waited in the gateway
longer than `command_max_age_s` since it was received), and none at all with
`commands_enabled: false`.
Writes then go through the router at write priority, as a SCADA write would; the drive's own
exception comes back by its INVT name (`operation_failure` for 04H), the gateway's as its reason.
"""

from __future__ import annotations

import logging
import struct
import time
from typing import Any, Final

from gateway.config import MqttConfig
from gateway.errors import (
    CommandRefused,
    DriveException,
    DriveOffline,
    GatewayPathUnavailable,
    GatewayTargetFailed,
    ModbusError,
    QueueFull,
)
from gateway.modbus.functions import is_exception
from gateway.mqtt.requests import (
    BRIDGE_READ_KEYS,
    BRIDGE_WRITE_KEYS,
    Json,
    RegisterRead,
    RegisterWrite,
    check_age,
    check_keys,
    check_waited,
    error_response,
    ok_response,
    parse_object,
    parse_read,
    parse_set,
    parse_write,
    transaction_of,
)
from gateway.poller import Poller
from gateway.profile import DriveProfile, describe_exception, exception_name, get_profile
from gateway.router import MAX_READ_WORDS, Router

log = logging.getLogger(__name__)

MQTT_CLIENT: Final = "mqtt"
"""The bus's name for requests from MQTT (its own round-robin share, like one SCADA client)."""


class CommandHandler:
    def __init__(
        self,
        config: MqttConfig,
        router: Router,
        poller: Poller,
        models: dict[str, str],
    ) -> None:
        self.config = config
        self.router = router
        self.poller = poller
        self.profiles: dict[str, DriveProfile] = {n: get_profile(m) for n, m in models.items()}
        self.executed = 0
        self.refused = 0

    # Each takes `received_at`, the monotonic time the bridge received the message: what waited
    # longer than `command_max_age_s` before its turn came is refused, not run late.

    async def drive_set(
        self, drive: str, payload: bytes, retained: bool, received_at: float
    ) -> Json:
        """`<base>/<drive>/set` → the `<base>/<drive>/set/response` payload."""
        return await self._answer(
            payload, retained, received_at, True, lambda m: self._set(drive, m)
        )

    async def write_parameter(self, payload: bytes, retained: bool, received_at: float) -> Json:
        return await self._answer(payload, retained, received_at, True, self._bridge_write)

    async def read_parameter(self, payload: bytes, retained: bool, received_at: float) -> Json:
        # A read changes nothing on the drive: monitoring-only gateways still answer it.
        return await self._answer(payload, retained, received_at, False, self._bridge_read)

    async def drive_get(
        self, drive: str, payload: bytes, retained: bool, received_at: float
    ) -> bool:
        """`<base>/<drive>/get`: poll the drive now. False when the request was ignored."""
        if retained:
            log.warning("ignored a retained message on %s/get", drive)
            return False
        try:
            check_waited(received_at, self.config.command_max_age_s, time.monotonic())
        except CommandRefused as exc:
            log.info("MQTT %s/get ignored: %s", drive, exc)
            return False
        await self.poller.refresh(drive)
        return True

    # -- one command, start to answer --------------------------------------------------------

    async def _answer(
        self, payload: bytes, retained: bool, received_at: float, writes: bool, run: Any
    ) -> Json:
        transaction: Any = None
        try:
            message = parse_object(payload)
            transaction = transaction_of(message)
            self._check_allowed(message, retained, writes)
            check_waited(received_at, self.config.command_max_age_s, time.monotonic())
            data: Json = await run(message)
        except CommandRefused as exc:
            self.refused += 1
            log.warning("MQTT command refused (%s): %s", exc.reason, exc)
            return error_response(transaction, exc.reason, str(exc))
        except ModbusError as exc:
            self.refused += 1
            error, code = modbus_error(exc)
            return error_response(transaction, error, str(exc), code)
        self.executed += 1
        return ok_response(transaction, data)

    def _check_allowed(self, message: Json, retained: bool, writes: bool) -> None:
        if retained:
            raise CommandRefused(
                "retained", "a retained command is never executed: publish without retain"
            )
        if writes and not self.config.commands_enabled:
            raise CommandRefused(
                "commands_disabled", "this gateway is monitoring only (commands_enabled: false)"
            )
        check_age(message, self.config.command_max_age_s, time.time())

    async def _set(self, drive: str, message: Json) -> Json:
        write = parse_set(message, self._profile(drive))
        await self._write(drive, write)
        return write.echo

    async def _bridge_write(self, message: Json) -> Json:
        check_keys(message, BRIDGE_WRITE_KEYS)
        drive = self._drive_named(message)
        write = parse_write(message, self._profile(drive))
        await self._write(drive, write)
        return {"drive": drive, **write.echo}

    async def _bridge_read(self, message: Json) -> Json:
        check_keys(message, BRIDGE_READ_KEYS)
        drive = self._drive_named(message)
        read = parse_read(message, self._read_limit(drive))
        words = await self._read(drive, read)
        return {"drive": drive, **read.echo, **read.result(words)}

    # -- the bus -----------------------------------------------------------------------------

    async def _write(self, drive: str, write: RegisterWrite) -> None:
        await self._execute(drive, write.pdu)
        log.info("MQTT command to %s done: %s", drive, write.echo)
        self.poller.after_write(drive)

    async def _read(self, drive: str, read: RegisterRead) -> list[int]:
        reply = await self._execute(drive, read.pdu)
        return list(struct.unpack(f">{read.count}H", reply[2 : 2 + 2 * read.count]))

    async def _execute(self, drive: str, pdu: bytes) -> bytes:
        route = self.router.route_for_drive(drive)
        reply = await self.router.execute(route.unit_id, pdu, client=MQTT_CLIENT)
        assert reply is not None  # only broadcasts have none
        if is_exception(reply):
            code = reply[1] if len(reply) > 1 else 0
            raise DriveException(pdu[0], code, describe_exception(code))
        return reply

    def _drive_named(self, message: Json) -> str:
        drive = message.get("drive")
        if not isinstance(drive, str) or drive not in self.profiles:
            known = ", ".join(sorted(self.profiles))
            raise CommandRefused("unknown_drive", f"drive must be one of: {known}")
        return drive

    def _profile(self, drive: str) -> DriveProfile:
        return self.profiles[drive]

    def _read_limit(self, drive: str) -> int:
        # When the router splits reads for this drive (on by default for INVT models), one
        # message may ask for what one Modbus read can carry; otherwise the drive's own limit.
        if self.router.route_for_drive(drive).max_words is not None:
            return MAX_READ_WORDS
        return self._profile(drive).max_words


def modbus_error(exc: ModbusError) -> tuple[str, int]:
    """The response's `error` and `exception_code` for a Modbus exception, drive's or gateway's."""
    if isinstance(exc, DriveException):
        return exception_name(exc.code), exc.code
    if isinstance(exc, DriveOffline):
        return "offline", exc.code
    if isinstance(exc, GatewayTargetFailed):
        return "timeout", exc.code
    if isinstance(exc, QueueFull):
        return "busy", exc.code
    if isinstance(exc, GatewayPathUnavailable):
        return "unavailable", exc.code
    return exception_name(exc.code), exc.code
