"""A gate in front of an active bus's port (`SerialLine.on_open`): once another master has been
heard (`close`), every write through the port is refused with PortError, whoever asks: the bus's
next request, a retry of the one on the wire, a marker, a frame chosen a moment before and held
for the gap's end. Nothing else of the port changes: it goes on reading until the bus, closed
with it, closes the port.

Installed only with `redundancy:`: a port without it is written to directly."""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from typing import Any, TypeVar

from gateway.bus.port import Port
from gateway.errors import PortError

R = TypeVar("R")


class WriteGate:
    """One bus's gate, open until `close`; it gates every port its line opens."""

    def __init__(self) -> None:
        self.reason: str | None = None
        """Why nothing may be written any more; None: the gate is open."""
        self.refused = 0
        """Writes refused: frames that would have gone out after another master was heard."""

    def close(self, reason: str) -> None:
        self.reason = reason

    def install(self, port: Port) -> None:
        """Put the gate in front of `port`'s writes (the line has just opened it): each of its
        write methods replaced, on this port object only, by one that asks the gate first."""
        gated: dict[str, Callable[..., Any]] = {
            "write_now": self._gated(port, port.write_now),
            "write_whole": self._gated(port, port.write_whole),
            "write": self._gated_async(port, port.write),
        }
        for name, write in gated.items():
            setattr(port, name, write)

    def _gated(self, port: Port, write: Callable[[bytes], R]) -> Callable[[bytes], R]:
        def gated(frame: bytes) -> R:
            self._check(port)
            return write(frame)

        return gated

    def _gated_async(
        self, port: Port, write: Callable[[bytes], Awaitable[None]]
    ) -> Callable[[bytes], Awaitable[None]]:
        async def gated(frame: bytes) -> None:
            self._check(port)
            await write(frame)

        return gated

    def _check(self, port: Port) -> None:
        if self.reason is not None:
            self.refused += 1
            raise PortError(f"{port.settings.port}: nothing sent: {self.reason}")
