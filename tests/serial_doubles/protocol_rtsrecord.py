"""`rtsrecord://PATH`: a serial port on PATH (a pty) that records what a UART with an RS-485
transceiver would see: RTS changes, writes and drains, each with its `time.monotonic()`.

A pty has no RTS line (setting it fails with ENOTTY) and no parity bit: this double keeps RTS in
memory, opens the pty without parity, and passes the bytes through unchanged, so a simulated
drive on the pty's other end still answers. It is the only stand-in here for real hardware.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, ClassVar

import serial


@dataclass(frozen=True)
class Event:
    at: float
    what: str
    """"rts", "write" or "drained"."""
    value: object = None
    """The RTS level for "rts", the bytes for "write"."""


class Serial(serial.Serial):
    recorded: ClassVar[dict[str, list[Event]]] = {}
    """Events by pty path, for the test to read."""

    # The ignores below are for pyserial's internals: types-pyserial stubs `port` as a property
    # (which mypy gives no `.setter` or `__set__` when reached through the class) and leave out
    # the private `_reconfigure_port` and `_rts_state` this double overrides and reads.
    @serial.Serial.port.setter  # type: ignore[attr-defined,untyped-decorator]
    def port(self, value: str | None) -> None:
        if value is not None and "://" in value:
            value = value.split("://", 1)[1]
        serial.Serial.port.__set__(self, value)  # type: ignore[attr-defined]

    def _reconfigure_port(self, force_update: bool = False) -> None:
        self._parity = serial.PARITY_NONE  # a pty refuses PARENB the second time
        super()._reconfigure_port(force_update)  # type: ignore[misc]

    def _update_rts_state(self) -> None:
        rts = bool(self._rts_state)  # type: ignore[attr-defined]
        self._events().append(Event(time.monotonic(), "rts", rts))

    def write(self, data: Any) -> int | None:
        self._events().append(Event(time.monotonic(), "write", bytes(data)))
        return super().write(data)

    def flush(self) -> None:
        super().flush()
        self._events().append(Event(time.monotonic(), "drained"))

    def _events(self) -> list[Event]:
        return self.recorded.setdefault(str(self.portstr), [])
