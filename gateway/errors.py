"""Every error the gateway raises, grouped by what the caller can do about it.

    GatewayError
    ├── ConfigError             the YAML file is wrong: names the key path and the reason; no start
    ├── MalformedFrame          bytes that are not a Modbus frame: close that connection only
    ├── LineError               one attempt on the wire failed; internal to the bus, which retries
    │   ├── ReplyTimeout        no reply (or not all of it) within the response timeout
    │   ├── BadReply            bad CRC, truncated, wrong address or function, echo mismatch, noise
    │   └── PortError           the serial port is closed, vanished or can't be opened
    └── ModbusError             answered to the client as a Modbus exception (has `code`)
        ├── DriveException      the drive itself answered an exception (its code, byte-exact)
        ├── GatewayPathUnavailable   0x0A: unknown unit id, queue full, broadcast not allowed
        │   └── QueueFull
        └── GatewayTargetFailed      0x0B: no valid reply after retries, drive offline, port lost
            ├── DriveOffline
            └── BusClosed        the gateway is shutting down: nobody's fault, nothing to retry

A `LineError` becomes `GatewayTargetFailed` in exactly one place: the bus's retry policy
(`gateway.bus.bus.Bus`), once the retries are spent.
"""

from __future__ import annotations

from enum import IntEnum


class ExceptionCode(IntEnum):
    """Modbus exception codes by their standard names (INVT's own meanings: `gateway.profile`)."""

    ILLEGAL_FUNCTION = 0x01
    ILLEGAL_DATA_ADDRESS = 0x02
    ILLEGAL_DATA_VALUE = 0x03
    SERVER_DEVICE_FAILURE = 0x04
    ACKNOWLEDGE = 0x05
    SERVER_DEVICE_BUSY = 0x06
    NEGATIVE_ACKNOWLEDGE = 0x07
    MEMORY_PARITY_ERROR = 0x08
    GATEWAY_PATH_UNAVAILABLE = 0x0A
    GATEWAY_TARGET_FAILED = 0x0B


class GatewayError(Exception):
    """Base of every error raised by the gateway."""


class ConfigError(GatewayError):
    """The configuration is invalid. `problems` lists (key path, reason) pairs."""

    def __init__(self, problems: list[tuple[str, str]], source: str = "") -> None:
        self.problems = problems
        self.source = source
        lines = [f"{path}: {reason}" if path else reason for path, reason in problems]
        where = f"{source}: " if source else ""
        super().__init__(where + "invalid configuration\n  " + "\n  ".join(lines))


class MalformedFrame(GatewayError):
    """Bytes that cannot be a Modbus frame."""


class LineError(GatewayError):
    """One attempt on the serial line failed."""


class ReplyTimeout(LineError):
    """No complete reply within the response timeout."""

    def __init__(self, message: str, received: bytes = b"") -> None:
        super().__init__(message)
        self.received = received


class BadReply(LineError):
    """A reply arrived but cannot be the answer: `kind` says why (crc, truncated, address, ...)."""

    def __init__(self, kind: str, message: str, frame: bytes = b"") -> None:
        super().__init__(message)
        self.kind = kind
        self.frame = frame


class PortError(LineError):
    """The serial port is not usable (unplugged, permission denied, not there)."""


class ModbusError(GatewayError):
    """An error the Modbus client receives as an exception response with `code`."""

    code: int = ExceptionCode.SERVER_DEVICE_FAILURE

    def __init__(self, message: str = "", code: int | None = None) -> None:
        if code is not None:
            self.code = code
        super().__init__(message or f"Modbus exception {self.code:#04x}")


class DriveException(ModbusError):
    """The drive answered with an exception response; `function` is the request's function code."""

    def __init__(self, function: int, code: int, message: str = "") -> None:
        self.function = function
        super().__init__(message or f"drive answered exception {code:#04x}", code)


class GatewayPathUnavailable(ModbusError):
    """0x0A: the gateway has no path to that unit id, or cannot take the request now."""

    code = ExceptionCode.GATEWAY_PATH_UNAVAILABLE


class QueueFull(GatewayPathUnavailable):
    """The bus's queue is full; the request was refused rather than queued without bound."""


class GatewayTargetFailed(ModbusError):
    """0x0B: the drive gave no valid reply (after retries), is offline, or its port is lost."""

    code = ExceptionCode.GATEWAY_TARGET_FAILED


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
