"""Every error the gateway raises, grouped by what the caller can do about it.

    GatewayError
    ├── ConfigError             the YAML file is wrong: names the key path and the reason; no start
    ├── TlsSettingsError        a TLS file the configuration names can't be used (`key` names it):
    │                           the MQTT session says so loudly and tries again later
    ├── CannotListen            a port to serve on can't be bound: one line, exit code 1
    ├── StoreError              the event store's file can't be opened or used (names it and why):
    │   │                       events are kept in memory meanwhile
    │   └── DiskFull            its disk has no room (`storage.path`): nothing written, events wait
    ├── StoreRefused            the store's file is a newer release's: one line, exit code 4
    │   └── StoreInUse          another gateway holds the store's file (its pid): exit code 4
    ├── BrokerShared            another gateway is live on this one's MQTT base topic: exit code 4
    │                           (a reload onto it: refused)
    ├── ServiceFailed           the service can't go on: stop with exit code 1 (systemd restarts it)
    │   ├── BusFailed           a bus's coroutine died of a bug
    │   └── FeatureFailed       a feature's background work died of a bug
    ├── MalformedFrame          bytes a peer sent that break its protocol: close that connection
    │   └── MalformedPacket     an MQTT packet the demo broker can't take
    ├── LineError               one attempt on the wire failed; internal to the bus, which retries
    │   ├── ReplyTimeout        no reply (or not all of it) within the response timeout
    │   ├── BadReply            bad CRC, truncated, wrong address or function, echo mismatch, noise
    │   └── PortError           the serial port is closed, vanished or can't be opened
    ├── CommandRefused          an MQTT command refused before it reached the bus: `reason` says why
    ├── FieldError              a field tool failed: what happened, and what to check on site
    ├── MonitorError            `invt-gateway monitor` can't show the traffic: one line why
    ├── ControlUnavailable      the control socket (`invt-gateway reload`) can't be made or reached
    ├── TableError              a parameter table shipped in the package is malformed (file, line,
    │                           column): a packaging bug, found by the tests
    ├── DeviceFileError         a device file (`model: sdm630`, `file:PATH`) can't be used: names
    │                           the file and the key path (`points.flow.type`) and why
    ├── InstructionCountError   `bench --instructions`: the run is void (wrong reply, no count)
    ├── OperationError          a console request refused or failed, with its HTTP `status`
    │   └── EditRefused         a configuration edit from the console not applied (`details`:
    │                           each problem with its key, when the text didn't check out)
    ├── OptionRefused           a command-line option's value the configuration refuses: names the
    │                           option, the value and why (exit code 2)
    └── ModbusError             answered to the client as a Modbus exception (has `code`)
        ├── DriveException      the drive itself answered an exception (its code, byte-exact)
        ├── RequestRefused      this side refuses a request with `code` (the simulated drive)
        ├── GatewayPathUnavailable   0x0A: unknown unit id, queue full, broadcast not allowed
        │   ├── StandbyRefusal   a standby gateway (`redundancy:`): the active one serves
        │   └── QueueFull
        └── GatewayTargetFailed      0x0B: no valid reply after retries, drive offline, port lost
            ├── DriveOffline
            └── BusClosed        the gateway is shutting down: nobody's fault, nothing to retry

A `LineError` becomes `GatewayTargetFailed` in exactly one place: the bus's retry policy
(`gateway.bus.bus.Bus`), once the retries are spent. A `ModbusError` becomes an exception PDU in
one place per front door: `gateway.tcp.server` for SCADA, `gateway.mqtt.commands` for MQTT.

`ExceptionCode` names each Modbus exception code once, by the standard's names; what INVT means
by 04H-09H (06H is "data frame error" there, not "busy") is the profile's
(`gateway.profile.exception_codes`).
"""

from __future__ import annotations

from collections.abc import Sequence
from enum import IntEnum
from typing import Any


class ExceptionCode(IntEnum):
    """Modbus exception codes (application protocol V1.1b3, section 7), one name each."""

    ILLEGAL_FUNCTION = 0x01
    ILLEGAL_DATA_ADDRESS = 0x02
    ILLEGAL_DATA_VALUE = 0x03
    SERVER_DEVICE_FAILURE = 0x04
    ACKNOWLEDGE = 0x05
    SERVER_DEVICE_BUSY = 0x06
    NEGATIVE_ACKNOWLEDGE = 0x07
    """Not in V1.1b3 (the older PI-MBUS-300 has it); INVT uses 07H for "parameter read-only"."""
    MEMORY_PARITY_ERROR = 0x08
    UNASSIGNED_09 = 0x09
    """The standard leaves 09H unassigned; INVT uses it for "password protection"."""
    GATEWAY_PATH_UNAVAILABLE = 0x0A
    GATEWAY_TARGET_FAILED = 0x0B


class GatewayError(Exception):
    """Base of every error raised by the gateway."""


class ConfigError(GatewayError):
    """The configuration is invalid. `problems` lists (key path, reason) pairs; `lines`, where
    given, each one's line in the file (None where it has none), shown before it."""

    def __init__(
        self,
        problems: list[tuple[str, str]],
        source: str = "",
        lines: list[int | None] | None = None,
    ) -> None:
        self.problems = problems
        self.source = source
        self.lines = lines if lines is not None else [None] * len(problems)
        said = [
            (f"line {line}: " if line is not None else "")
            + (f"{path}: {reason}" if path else reason)
            for (path, reason), line in zip(problems, self.lines, strict=True)
        ]
        where = f"{source}: " if source else ""
        super().__init__(where + "invalid configuration\n  " + "\n  ".join(said))


class TlsSettingsError(GatewayError):
    """A TLS file of the configuration can't be used; `key` names it (`mqtt.ca_file`)."""

    def __init__(self, key: str, path: str | None, reason: str) -> None:
        super().__init__(f"{key} ({path}): {reason}")
        self.key = key
        self.reason = reason


class ServiceFailed(GatewayError):
    """The service can't go on; it stops with exit code 1 so its service manager restarts it."""


class BusFailed(ServiceFailed):
    """The bus's coroutine died: the service can't serve this line and must be restarted."""


class FeatureFailed(ServiceFailed):
    """A feature's background work died of a bug: the service stops (exit code 1) so that its
    manager restarts it, rather than run on without, say, its polls."""


class MalformedFrame(GatewayError):
    """Bytes a peer sent that break its protocol (a Modbus frame, an MQTT packet)."""


class MalformedPacket(MalformedFrame):
    """An MQTT client broke MQTT 3.1.1 (seen by the demo broker): close its connection."""


class LineError(GatewayError):
    """One attempt on the serial line failed."""


class ReplyTimeout(LineError):
    """No complete reply within the response timeout."""

    def __init__(
        self, message: str, received: bytes = b"", strays: tuple[tuple[bytes, float], ...] = ()
    ) -> None:
        super().__init__(message)
        self.received = received
        self.strays = strays
        """Whole, sound frames set aside during the attempt and the drain after it, with when
        each was heard (`gateway.bus.late_replies`)."""


class BadReply(LineError):
    """A reply arrived but cannot be the answer: `kind` says why (crc, truncated, address, ...)."""

    def __init__(self, kind: str, message: str, frame: bytes = b"") -> None:
        super().__init__(message)
        self.kind = kind
        self.frame = frame
        self.strays: tuple[tuple[bytes, float], ...] = ()
        """Whole, sound frames set aside during the attempt and the drain after it
        (`ReplyTimeout.strays`)."""


class PortError(LineError):
    """The serial port is not usable (unplugged, permission denied, not there)."""


class CommandRefused(GatewayError):
    """The gateway refuses an MQTT command without sending anything to the drive."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


class FieldError(GatewayError):
    """A field tool's failure: what happened, and what to check."""

    def __init__(self, message: str, checks: Sequence[str] = ()) -> None:
        super().__init__(message)
        self.message = message
        self.checks = tuple(checks)
        self.exception_code: int | None = None
        """The drive's exception code when the failure is its exception reply."""

    def __str__(self) -> str:
        if not self.checks:
            return self.message
        return self.message + "\ncheck:\n" + "\n".join(f"  - {check}" for check in self.checks)


class ModbusError(GatewayError):
    """An error the Modbus client receives as an exception response with `code`."""

    code: int = ExceptionCode.SERVER_DEVICE_FAILURE

    def __init__(self, message: str = "", code: int | None = None) -> None:
        if code is not None:
            self.code = code
        super().__init__(message or f"Modbus exception {self.code:#04x}")


class DriveException(ModbusError):
    """The drive answered with an exception response; `function` is the request's function code."""

    def __init__(self, function: int, code: int, message: str = "", name: str = "") -> None:
        self.function = function
        self.name = name
        """The drive's own name for `code`, from its profile (`data_frame_error` for an INVT
        drive's 06H, `server_device_busy` for another's); "" where no profile was at hand."""
        super().__init__(message or f"drive answered exception {code:#04x}", code)


class RequestRefused(ModbusError):
    """This side refuses a request with exception `code` (the simulated drive answers so)."""

    def __init__(self, code: int, reason: str) -> None:
        super().__init__(reason, code)


class GatewayPathUnavailable(ModbusError):
    """0x0A: the gateway has no path to that unit id, or cannot take the request now."""

    code = ExceptionCode.GATEWAY_PATH_UNAVAILABLE


class StandbyRefusal(GatewayPathUnavailable):
    """0x0A from a standby gateway (`redundancy:`): the active one serves the drives; this one
    never transmits on their line."""


class QueueFull(GatewayPathUnavailable):
    """The bus's queue is full; the request was refused rather than queued without bound."""


class GatewayTargetFailed(ModbusError):
    """0x0B: the drive gave no valid reply (after retries), is offline, or its port is lost."""

    code = ExceptionCode.GATEWAY_TARGET_FAILED
    sent_unconfirmed = 0
    """A write that went out this many times with no reply confirming it: the drive may have
    carried it out all the same (0: not a write, or it never went out)."""


class DriveOffline(GatewayTargetFailed):
    """The drive is isolated after repeated timeouts; answered at once, without bus time."""


class BusClosed(GatewayTargetFailed):
    """The bus is closed (the gateway is shutting down): the drive did nothing wrong.

    Lets a caller tell shutdown from a drive that failed without asking the bus for its state.
    """


class CannotListen(GatewayError):
    """A port the gateway serves on can't be bound: the service can't start (exit code 1).

    Its message is one line a person can act on: what, where, and the likely cause.
    """


class BrokerShared(GatewayError):
    """Another gateway is live on this one's MQTT base topic: the service can't start (exit
    code 4), or a reload onto that base topic is refused (the running configuration stays;
    `invt-gateway reload` exits 3); the message names the other gateway and the keys to
    change."""


class StoreError(GatewayError):
    """The event store's database could not be opened or used (the message names the file and
    why): the gateway goes on, keeping events in memory."""


class DiskFull(StoreError):
    """The store's disk is full (`Room.full`): nothing was written."""


class TableError(GatewayError, ValueError):
    """A parameter table's data file is malformed: the message names the file, the line and the
    column."""


class DeviceFileError(GatewayError, ValueError):
    """A device file that can't be used: the message names the file, the key path and why (a
    ValueError, so the configuration's `model` check reports it under the drive's key)."""


class StoreRefused(GatewayError):
    """The store's file was written by a newer release (its schema is past this release's): not
    opened, not re-marked; the gateway doesn't start (one line, exit code 4)."""


class StoreInUse(StoreRefused):
    """Another process holds the store's file (`gateway.store.owner`): the message names the file
    and the holder's pid; the gateway doesn't start (one line, exit code 4), the holder runs on."""


class MonitorError(GatewayError):
    """Why `invt-gateway monitor` can't show the traffic, in one line."""


class ControlUnavailable(GatewayError):
    """The control socket can't be made (the gateway reloads on SIGHUP only) or reached (no
    gateway runs with that file here); the message says why."""


class InstructionCountError(GatewayError):
    """`invt-gateway bench --instructions`: the run is void (a wrong reply, or callgrind wrote no
    count)."""


class OperationError(GatewayError):
    """A console request told to the caller with an HTTP status: 400 bad input, 403 refused,
    409 disabled, 502 the drive or the line failed."""

    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status = status


class EditRefused(OperationError):
    """A configuration edit from the console was not applied; `details` is the check's findings
    (`Checked.to_json()`) when the text didn't check out or the reload refused it."""

    def __init__(self, status: int, message: str, details: dict[str, Any] | None = None) -> None:
        super().__init__(status, message)
        self.details = details


class OptionRefused(GatewayError):
    """A command-line option's value the configuration refuses (`--port 70000`): the message
    names the option, the value and why."""
