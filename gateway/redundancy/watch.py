"""An active gateway's watch on one of its lines: a request it did not send is another master's.

Every read from the bus's port passes here first (`SerialLine.on_heard`), cut into frames
(`gateway.redundancy.frames`). The bus's own frames are known: the transaction it carries (the
request, or the marker before it: `Carrier.carrying`, `Carrier.marker_sent`), remembered for a
while, so an adapter's echo of our own request, or the drive's copy of our 06H write coming
late, is ours. A request that is none of these came from another master: the watch tells
`foreign` at once, which closes the line's write gate (`gateway.redundancy.gate`) and the bus
(`Redundancy.foreign_master`).

A drive's reply proves nothing by itself (ours may come late, after every drain): only
requests, which drives never send, are another master's mark. 05H, 06H and 08H read the same
either way: one of them that is not ours counts too (a late copy of an older write of ours is
remembered with `OWN_FRAMES`).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from typing import Final

from gateway.bus import Bus
from gateway.modbus.rtu import build_frame
from gateway.redundancy.frames import Frame, Kind
from gateway.redundancy.gate import WriteGate
from gateway.redundancy.listener import LineEar

OWN_FRAMES: Final = 64
"""Our own frames remembered: more than a drain's worth of late replies."""

Foreign = Callable[[str, bytes], None]
"""Told (bus name, the frame) when another master's frame is heard."""
Lost = Callable[[], None]
"""Told when the bus's port is lost (the role machine counts the time without a port)."""


class ActiveWatch:
    """Hooked on one active bus's line for as long as that bus runs: every read
    (`SerialLine.on_heard`), and a gate in front of every write (`SerialLine.on_open`)."""

    def __init__(self, bus: Bus, foreign: Foreign, lost: Lost | None = None) -> None:
        self.bus = bus
        self._foreign = foreign
        self._lost = lost
        self.gate = WriteGate()
        bus.line.on_heard = self.heard
        bus.line.on_open = self.gate.install
        # One watch per bus: a reload's bus takes its predecessor's listeners, a watch's too.
        listeners = bus.observers.port_listeners
        listeners[:] = [
            known
            for known in listeners
            if not isinstance(getattr(known, "__self__", None), ActiveWatch)
        ]
        bus.add_port_listener(self._port)
        self._own: deque[bytes] = deque(maxlen=OWN_FRAMES)
        self.ear = LineEar(bus.settings.line, self._frame)
        self.foreign_frames = 0

    def heard(self, data: bytes) -> None:
        """The port's reader callback has read `data` (before the line takes it in)."""
        self._note_own()
        self.ear.heard(data)

    def _note_own(self) -> None:
        carrier = self.bus.carrier
        carrying = carrier.carrying
        own = self._own
        if carrying is not None:
            frame = carrying.frame or build_frame(carrying.address, carrying.pdu)
            if not own or own[-1] != frame:
                own.append(frame)
        marker = carrier.marker_sent
        if marker is not None and marker not in own:
            own.append(marker)

    def _frame(self, frame: Frame) -> None:
        if frame.kind is Kind.REPLY:
            return
        self._note_own()
        if frame.data in self._own:
            return
        self.foreign_frames += 1
        self._foreign(self.bus.name, frame.data)

    def _port(self, bus: str, port: str, lost: bool, reason: str) -> None:
        if lost and self._lost is not None:
            self._lost()

    def close(self) -> None:
        self.ear.close()
        listeners = self.bus.observers.port_listeners
        if self._port in listeners:
            listeners.remove(self._port)
