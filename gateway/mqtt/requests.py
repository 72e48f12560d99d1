"""MQTT command payloads read into bus requests, and the answers written back. No I/O.

This module reads JSON: keys, types, spellings. What a command means in registers (on an INVT
drive a command with a set-point is one 10H write of 2000H-2001H; a RAM-only write's address; a
register's decimals) is the drive's profile's (`DriveProfile.control_writes` and its kin).

A command is refused before it reaches the bus when it is malformed, retained, stale or its value
can't be written; every refusal is a `CommandRefused` with a short `reason` the response carries
(`invalid_request`, `invalid_value`, `stale`, `retained`, `commands_disabled`, `unknown_drive`).

Payloads (JSON objects; `transaction` is echoed, `time` is when it was sent):
    <base>/<drive>/set     {"command": "run_forward", "frequency_hz": 35.0}
                           {"frequency_hz": 35.0}
                           {"parameter": "P00.11", "value": 10.0, "ram_only": true}
                           {"parameter": "2001H", "raw": 3500}
                           {"point": "demand_period", "value": 15}   (a device file's point)
    bridge/request/read_parameter   {"drive": "pump1", "parameter": "P07.27", "count": 6}
    bridge/request/write_parameter  {"drive": "pump1", "parameter": "P00.11", "value": 10.0}
"""

from __future__ import annotations

import json
import math
import struct
from dataclasses import dataclass, field
from datetime import datetime
from typing import Any, Final

from gateway.errors import CommandRefused
from gateway.modbus.functions import (
    READ_HOLDING_REGISTERS,
    WRITE_MULTIPLE_REGISTERS,
    WRITE_SINGLE_COIL,
    WRITE_SINGLE_REGISTER,
)
from gateway.profile import DriveProfile, format_register, parse_register
from gateway.profile import RegisterWrite as Step
from gateway.profile.addressing import format_parameter, is_parameter_register
from gateway.profile.commands import is_signed, known_decimals
from gateway.profile.point_types import Table
from gateway.profile.points import for_series

COIL_ON: Final = 0xFF00
"""05H's word for "on" (0000H is off; Modbus allows no other)."""
MILLISECONDS_EPOCH: Final = 1e11
"""A `time` above this is taken as milliseconds (JavaScript's Date.now()), not seconds."""

COMMON_KEYS: Final = frozenset({"transaction", "time"})
WRITE_KEYS: Final = frozenset({"parameter", "register", "value", "raw", "decimals", "ram_only"})
SET_KEYS: Final = COMMON_KEYS | WRITE_KEYS | {"command", "frequency_hz", "point"}
BRIDGE_WRITE_KEYS: Final = COMMON_KEYS | WRITE_KEYS | {"drive"}
BRIDGE_READ_KEYS: Final = COMMON_KEYS | {"drive", "parameter", "register", "count", "decimals"}

Json = dict[str, Any]


@dataclass(frozen=True, slots=True)
class RegisterWrite:
    """Words for the drive from `start` (06H for one word, 10H for several)."""

    start: int
    words: tuple[int, ...]
    echo: Json = field(default_factory=dict)
    """What the acknowledgement repeats of the command."""
    pause_s: float = 0.0
    """The wait after this write before the next of `then`."""
    then: tuple[Step, ...] = ()
    """Further writes of the same command, in order (a drive whose state machine takes
    several control words to start)."""

    coil: bool = False
    """A coil's state (05H, words[0] 1 = on), not registers."""

    @property
    def pdu(self) -> bytes:
        return _write_pdu(self.start, self.words, self.coil)

    @property
    def steps(self) -> tuple[tuple[bytes, float], ...]:
        """Each write's PDU and the pause after it, in order."""
        first = (self.pdu, self.pause_s)
        rest = ((_write_pdu(s.start, s.words, s.table is Table.COIL), s.pause_s) for s in self.then)
        return (first, *rest)


def _write_pdu(start: int, words: tuple[int, ...], coil: bool = False) -> bytes:
    if coil:
        return struct.pack(">BHH", WRITE_SINGLE_COIL, start, COIL_ON if words[0] else 0)
    if len(words) == 1:
        return struct.pack(">BHH", WRITE_SINGLE_REGISTER, start, words[0])
    count = len(words)
    header = struct.pack(">BHHB", WRITE_MULTIPLE_REGISTERS, start, count, 2 * count)
    return header + struct.pack(f">{count}H", *words)


@dataclass(frozen=True, slots=True)
class RegisterRead:
    start: int
    count: int
    decimals: int | None
    signed: bool
    echo: Json = field(default_factory=dict)

    @property
    def pdu(self) -> bytes:
        return struct.pack(">BHH", READ_HOLDING_REGISTERS, self.start, self.count)

    def result(self, words: list[int]) -> Json:
        values = [_engineering(w, self.decimals, self.signed) for w in words]
        if self.count == 1:
            return {"raw": words[0], "value": values[0]}
        return {"raw": words, "value": values}


# -- reading a payload ------------------------------------------------------------------------


def parse_object(payload: bytes | bytearray | str) -> Json:
    try:
        message = json.loads(payload)
    except (ValueError, UnicodeDecodeError) as exc:
        raise CommandRefused("invalid_request", f"not JSON: {exc}") from None
    if not isinstance(message, dict):
        raise CommandRefused("invalid_request", "the payload must be a JSON object")
    return message


def transaction_of(message: Json) -> Any:
    return message.get("transaction")


def check_keys(message: Json, allowed: frozenset[str]) -> None:
    # An unknown key is almost always a typo ("frequency": 35) that would silently do nothing.
    unknown = sorted(set(message) - allowed)
    if unknown:
        raise CommandRefused(
            "invalid_request",
            f"unknown key {', '.join(map(repr, unknown))}: use {', '.join(sorted(allowed))}",
        )


def check_age(message: Json, max_age_s: float, now: float) -> None:
    """Refuse a command whose `time` (epoch s or ms, or ISO 8601) is older than `max_age_s`."""
    sent = message.get("time")
    if sent is None:
        return
    at = _epoch(sent)
    age = now - at
    if age > max_age_s:
        raise CommandRefused("stale", f"sent {age:.1f} s ago, more than {max_age_s:g} s: refused")
    if age < -max_age_s:
        raise CommandRefused(
            "stale", f"sent {-age:.1f} s in the future: the sender's clock is wrong, refused"
        )


def check_waited(received_at: float, max_age_s: float, now: float) -> None:
    """Refuse a command that waited in the gateway longer than `max_age_s` before it could start.

    `time` is optional (Home Assistant's buttons send none), so the sender's clock can't be the
    only guard: a `run_forward` pressed while this drive's earlier commands were stuck must not
    run minutes later, when the queue clears and the plant may be in another state.
    `received_at` and `now` are monotonic.
    """
    waited = now - received_at
    if waited > max_age_s:
        raise CommandRefused(
            "stale",
            f"waited {waited:.1f} s in the gateway behind earlier requests, more than "
            f"{max_age_s:g} s: refused",
        )


def _epoch(sent: Any) -> float:
    if isinstance(sent, bool):
        raise CommandRefused("invalid_request", "time must be epoch seconds or ISO 8601")
    if isinstance(sent, int | float):
        return sent / 1000 if sent > MILLISECONDS_EPOCH else float(sent)
    if isinstance(sent, str):
        try:
            parsed = datetime.fromisoformat(sent)
        except ValueError:
            raise CommandRefused(
                "invalid_request", f"time {sent!r} is not ISO 8601 (2024-05-01T12:00:00Z)"
            ) from None
        if parsed.tzinfo is None:
            raise CommandRefused("invalid_request", f"time {sent!r} has no time zone")
        return parsed.timestamp()
    raise CommandRefused("invalid_request", "time must be epoch seconds or ISO 8601")


def parse_set(message: Json, profile: DriveProfile) -> RegisterWrite:
    """A `<drive>/set` payload: a control command (with a set-point), a set-point alone, or a
    parameter write."""
    check_keys(message, SET_KEYS)
    if "point" in message:
        return parse_point_write(message, profile)
    has_command = "command" in message
    has_frequency = "frequency_hz" in message
    has_write = bool(WRITE_KEYS & set(message))
    if has_write and (has_command or has_frequency):
        raise CommandRefused(
            "invalid_request", "one message is a command or a parameter write, not both"
        )
    if has_write:
        return parse_write(message, profile)
    if not has_command and not has_frequency:
        raise CommandRefused(
            "invalid_request", "nothing to do: give command, frequency_hz or parameter"
        )
    frequency = _frequency(message["frequency_hz"], profile) if has_frequency else None
    echo: Json = {}
    command = None
    if has_command:
        name = message["command"]
        if not isinstance(name, str):
            raise CommandRefused("invalid_request", "command must be a string")
        try:
            command = profile.command_name(name)
        except ValueError as exc:
            raise CommandRefused("invalid_request", str(exc)) from None
        echo["command"] = command
    if has_frequency:
        echo["frequency_hz"] = message["frequency_hz"]
    try:
        first, *rest = profile.control_writes(command, frequency)
    except ValueError as exc:
        raise CommandRefused("invalid_request", str(exc)) from None
    return RegisterWrite(first.start, first.words, echo, first.pause_s, tuple(rest))


def parse_point_write(message: Json, profile: DriveProfile) -> RegisterWrite:
    """`{"point": name, "value": v}`: a device file's writable point, `v` as it is published
    (scaled; an enumeration's words; a text; true or false for a coil)."""
    extra = sorted(set(message) - COMMON_KEYS - {"point", "value"})
    if extra or "value" not in message:
        raise CommandRefused(
            "invalid_request", 'a point write is {"point": name, "value": value} and nothing else'
        )
    name = message["point"]
    if not isinstance(name, str):
        raise CommandRefused("invalid_request", "point must be a point's name")
    try:
        write = profile.point_write(name, message["value"])
    except ValueError as exc:
        writable = any(p.name == name and p.writable for p in profile.typed_points)
        reason = "invalid_value" if writable else "invalid_request"  # the value, or the point
        raise CommandRefused(reason, str(exc)) from None
    echo: Json = {
        "point": name,
        "value": message["value"],
        "register": format_register(write.start),
    }
    return RegisterWrite(write.start, write.words, echo, coil=write.table is Table.COIL)


def _frequency(value: Any, profile: DriveProfile) -> int:
    number = _number(value, "frequency_hz")
    if number < 0:
        raise CommandRefused(
            "invalid_value", "frequency_hz must be 0 or more: use run_reverse for reverse"
        )
    try:
        return profile.setpoint_word(number)
    except ValueError as exc:
        raise CommandRefused("invalid_value", str(exc)) from None


def parse_write(message: Json, profile: DriveProfile) -> RegisterWrite:
    address, spelled = _address(message)
    has_value, has_raw = "value" in message, "raw" in message
    if has_value == has_raw:
        raise CommandRefused("invalid_request", "give either value or raw")
    ram_only = message.get("ram_only", False)
    if not isinstance(ram_only, bool):
        raise CommandRefused("invalid_request", "ram_only must be true or false")
    start = address
    if ram_only:  # where it goes first: a write that can't go anywhere needs no value checked
        try:
            start = profile.ram_only_address(address, spelled)
        except ValueError as exc:
            raise CommandRefused("invalid_request", str(exc)) from None
    if has_raw:
        raw = _raw(message["raw"])
    else:
        decimals = _decimals(message, address, profile)
        if decimals is None:
            raise CommandRefused(
                "invalid_value",
                f"the decimals of {spelled} are not in the profile: give decimals, or raw",
            )
        value = _number(message["value"], "value")
        if "decimals" in message:  # the caller's own scale: only the register's bounds apply
            raw = _scaled(value, decimals, spelled)
        else:  # the profile's point: resolution and range as `write` and the console check them
            raw = _encoded(value, address, profile)
    echo: Json = {"parameter": spelled, "register": format_register(address), "raw": raw}
    if has_value:
        echo["value"] = message["value"]
    if ram_only:
        echo["ram_only"] = True
    return RegisterWrite(start, (raw,), echo)


def parse_read(message: Json, max_count: int, profile: DriveProfile | None = None) -> RegisterRead:
    """`max_count`: the most words one read of this drive may ask for (the drive's word limit,
    or Modbus's own when the router splits longer reads for it); `profile`: the drive's, whose
    series table scales a parameter."""
    address, spelled = _address(message)
    count = message.get("count", 1)
    if isinstance(count, bool) or not isinstance(count, int) or not 1 <= count <= max_count:
        raise CommandRefused("invalid_request", f"count must be 1..{max_count}")
    if address + count > 0x10000:
        raise CommandRefused("invalid_request", f"count {count} from {spelled} passes FFFFH")
    decimals = _decimals(message, address, profile)
    signed = is_signed(address, profile)
    echo: Json = {"parameter": spelled, "register": format_register(address)}
    if count != 1:
        echo["count"] = count
    return RegisterRead(address, count, decimals, signed, echo)


def _address(message: Json) -> tuple[int, str]:
    given = [key for key in ("parameter", "register") if key in message]
    if len(given) != 1:
        raise CommandRefused("invalid_request", "give parameter (P00.11) or register (2001H)")
    spelled = message[given[0]]
    if isinstance(spelled, bool) or not isinstance(spelled, str | int):
        raise CommandRefused("invalid_request", f"{given[0]} must be like P00.11 or 2001H")
    try:
        address = spelled if isinstance(spelled, int) else parse_register(spelled)
    except ValueError as exc:
        raise CommandRefused("invalid_request", str(exc)) from None
    if not 0 <= address <= 0xFFFF:
        raise CommandRefused("invalid_request", f"register {address} is outside 0..65535")
    return address, str(spelled)


def _decimals(message: Json, address: int, profile: DriveProfile | None) -> int | None:
    if "decimals" in message:
        decimals = message["decimals"]
        if isinstance(decimals, bool) or not isinstance(decimals, int) or not 0 <= decimals <= 4:
            raise CommandRefused("invalid_request", "decimals must be 0..4")
        return decimals
    return known_decimals(address, profile)


def _number(value: Any, key: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise CommandRefused("invalid_value", f"{key} must be a number")
    return float(value)


def _raw(value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise CommandRefused("invalid_value", "raw must be an integer")
    if not -0x8000 <= value <= 0xFFFF:
        raise CommandRefused("invalid_value", f"raw {value} does not fit in one register")
    return value & 0xFFFF


def _encoded(value: float, address: int, profile: DriveProfile) -> int:
    """The word for `value` at `address` as the profile's point encodes it (`Point.encode`):
    refused, never rounded, when finer than the register holds or outside the manual's range."""
    name = format_parameter(address) if is_parameter_register(address) else format_register(address)
    point = for_series(profile.resolve(name), profile)
    try:
        return point.encode(repr(value))
    except ValueError as exc:
        raise CommandRefused("invalid_value", str(exc)) from None


def _scaled(value: float, decimals: int, spelled: str) -> int:
    scaled = value * float(10**decimals)
    if not math.isfinite(scaled):  # 1e308 with its decimals: round() would overflow
        raise CommandRefused("invalid_value", f"{spelled} = {value:g} does not fit in one register")
    raw = round(scaled)
    if not -0x8000 <= raw <= 0xFFFF:
        raise CommandRefused(
            "invalid_value", f"{spelled} = {value:g} ({raw} raw) does not fit in one register"
        )
    return raw & 0xFFFF


def _engineering(word: int, decimals: int | None, signed: bool) -> float | int:
    number = word - 0x10000 if signed and word & 0x8000 else word
    return number / float(10**decimals) if decimals else number


# -- writing an answer ------------------------------------------------------------------------


def ok_response(transaction: Any, data: Json) -> Json:
    response: Json = {"status": "ok", "data": data}
    if transaction is not None:
        response["transaction"] = transaction
    return response


def error_response(
    transaction: Any,
    error: str,
    message: str,
    exception_code: int | None = None,
    data: Json | None = None,
) -> Json:
    """`error`: the drive's name for its exception, its profile's (an INVT drive's 04H
    `operation_failure`, another's `server_device_failure`), or the gateway's reason."""
    response: Json = {"status": "error", "error": error, "message": message, "data": data or {}}
    if exception_code is not None:
        response["exception_code"] = exception_code
    if transaction is not None:
        response["transaction"] = transaction
    return response


def dump(payload: Json) -> str:
    """A payload as the bridge publishes it: compact JSON."""
    return json.dumps(payload, separators=(",", ":"))
