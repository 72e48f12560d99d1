"""Reading and writing single points, with failures turned into what to check.

Every error leaves here as a `FieldError` naming the request ("reading P00.11 at address 1")
and the checklist that fits: silence, garbage, a port that won't open, or the drive's own
exception code in its profile's words (INVT's when the model isn't given).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from gateway.errors import BadReply, FieldError, PortError, ReplyTimeout
from gateway.modbus.functions import READ_HOLDING_REGISTERS, WRITE_SINGLE_REGISTER, is_exception
from gateway.profile import DriveProfile, parse_parameter, profiles_for_identification
from gateway.profile.exception_codes import INVT_EXCEPTIONS
from gateway.profile.invt import IDENTIFICATION
from gateway.profile.points import Meaning, Point
from gateway.profile.ram_writes import ram_write_address
from gateway.tools.advice import (
    COMMUNICATION_MODE,
    GARBLED,
    GATEWAY,
    NO_ANSWER,
    PORT,
    exception_error,
)
from gateway.tools.masters import Master, TcpMaster

RUN_COMMAND_CHANNEL = "P00.01"
COMMUNICATION_CHANNEL = 2
FREQUENCY_COMMAND = "P00.06"
MODBUS_FREQUENCY = 8


@dataclass(frozen=True)
class Reading:
    point: Point
    raw: int
    profile: DriveProfile | None = None
    """The drive's series, when known: 2101H bit 0 and fault names depend on it."""

    def line(self) -> str:
        """ "P00.11  10.0 s  (000BH = 0064H: acceleration time 1)"."""
        return (
            f"{self.point.label}  {self.point.show(self.raw, self.profile)}  "
            f"({self.point.where} = {self.raw:04X}H: {self.point.description})"
        )


def ask(
    master: Master, address: int, pdu: bytes, what: str, profile: DriveProfile | None = None
) -> bytes:
    """The reply PDU to `pdu`; a FieldError for silence, garbage, a lost port or an exception
    (in `profile`'s words; INVT's without one: the field tools' drives are INVT's unless
    `--model` says otherwise)."""
    via_gateway = isinstance(master, TcpMaster)
    try:
        reply = master.request(address, pdu)
    except ReplyTimeout as exc:
        checks = GATEWAY if via_gateway else NO_ANSWER
        raise FieldError(f"{what}: no answer from {master.where} ({exc})", checks) from exc
    except BadReply as exc:
        raise FieldError(f"{what}: garbled reply on {master.where} ({exc})", GARBLED) from exc
    except PortError as exc:
        raise FieldError(f"{what}: {exc}", GATEWAY if via_gateway else PORT) from exc
    if is_exception(reply):
        code = reply[1] if len(reply) > 1 else 0
        raise exception_error(
            code, what, INVT_EXCEPTIONS if profile is None else profile.exceptions
        )
    return reply


def read_point(
    master: Master, address: int, point: Point, profile: DriveProfile | None = None
) -> Reading:
    what = f"reading {point.label} ({point.where}) at address {address}"
    pdu = struct.pack(">BHH", READ_HOLDING_REGISTERS, point.address, 1)
    reply = ask(master, address, pdu, what, profile)
    if len(reply) != 4 or reply[:2] != bytes((READ_HOLDING_REGISTERS, 2)):
        raise FieldError(f"{what}: unexpected reply {reply.hex(' ')}", GARBLED)
    return Reading(point, int.from_bytes(reply[2:4], "big"), profile)


def write_point(
    master: Master,
    address: int,
    point: Point,
    raw: int,
    *,
    ram: bool = False,
    profile: DriveProfile | None = None,
) -> str:
    """Write one word with 06H; the confirmation line, with a warning if the drive won't obey."""
    register = ram_write_address(point.address) if ram else point.address
    what = f"writing {point.label} ({point.where}) at address {address}"
    pdu = struct.pack(">BHH", WRITE_SINGLE_REGISTER, register, raw)
    reply = ask(master, address, pdu, what, profile)
    if reply != pdu:
        raise FieldError(f"{what}: the echo {reply.hex(' ')} differs from the request", GARBLED)
    where = f"{register:04X}H, RAM only" if register != point.address else point.where
    # What is written is never a status word, whose words alone depend on the series.
    line = f"{point.label} <- {point.show(raw, None)}  ({where} = {raw:04X}H): written"
    warning = _communication_mode_warning(master, address, point)
    return line if warning is None else f"{line}\nwarning: {warning}"


def _communication_mode_warning(master: Master, address: int, point: Point) -> str | None:
    """The drive takes the write but ignores it unless it listens to Modbus: say so."""
    if point.meaning is Meaning.CONTROL_WORD:
        name, wanted = RUN_COMMAND_CHANNEL, COMMUNICATION_CHANNEL
    elif point.label in ("frequency_setpoint", "2001H"):
        name, wanted = FREQUENCY_COMMAND, MODBUS_FREQUENCY
    else:
        return None
    try:
        reply = master.request(address, struct.pack(">BHH", 3, parse_parameter(name), 1))
    except (ReplyTimeout, BadReply, PortError):
        return None  # the write itself went through; this is advice, not a failure
    if is_exception(reply) or len(reply) != 4:
        return None
    actual = int.from_bytes(reply[2:4], "big")
    if actual == wanted:
        return None
    return f"{name} is {actual}, so the drive does not obey Modbus here: " + "; ".join(
        COMMUNICATION_MODE
    )


def series_of(master: Master, address: int) -> DriveProfile | None:
    """The one series the drive's 2103H code names; None when it names none or two (010AH), or
    the drive won't say (a generic device): the caller then shows what doesn't depend on it."""
    pdu = struct.pack(">BHH", READ_HOLDING_REGISTERS, IDENTIFICATION, 1)
    try:
        reply = ask(master, address, pdu, f"reading 2103H at address {address}")
    except FieldError:
        return None
    if len(reply) != 4:
        return None
    profiles = profiles_for_identification(int.from_bytes(reply[2:4], "big"))
    return profiles[0] if len(profiles) == 1 else None
