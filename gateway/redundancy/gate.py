"""A gate in front of an active bus's ports (`SerialLine.on_open`): once another master has
been heard (`close`), each port the line opened is silenced (`Port.silenced`), so every write
through it is refused with PortError, whoever asks: the bus's next request, a retry of the one
on the wire, a marker, a frame chosen a moment before and held for the gap's end. Nothing else
of the port changes: it goes on reading until the bus, closed with it, closes the port.

Installed only with `redundancy:`: a port without it is never silenced."""

from __future__ import annotations

from gateway.bus.port import Port


class WriteGate:
    """One bus's gate, open until `close`; it silences every port its line opens from then."""

    def __init__(self) -> None:
        self.reason: str | None = None
        """Why nothing may be written any more; None: the gate is open."""
        self._ports: list[Port] = []

    def close(self, reason: str) -> None:
        self.reason = reason
        for port in self._ports:
            port.silenced = reason

    def install(self, port: Port) -> None:
        """The line has just opened `port`: silenced with the others once the gate closes (at
        once, if it is closed already)."""
        self._ports = [known for known in self._ports if known.open] + [port]
        port.silenced = self.reason
