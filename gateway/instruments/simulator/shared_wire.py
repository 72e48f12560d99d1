"""Several masters on one simulated RS-485 pair (`simulate --masters N`): the redundancy tests'
line, where an active and a standby gateway are wired to the same drives.

RS-485 is one shared pair: every node hears every other. So here:

- each master has a pty of its own (its adapter); what one master transmits reaches the drives
  and, at once, every other master (they hear it, as a real adapter's receiver does);
- the drives' replies reach every master;
- a master's frame is on the wire for its characters' time (from its first byte, or the end of
  that master's previous frame); two transmissions that overlap in time, two masters' or a
  master's and a drive's reply, garble each other: a collision. The drives see a bad CRC and
  stay silent (a garbled reply reaches the masters with a bad CRC). Each collision is counted
  once, and on each master that took part.

A frame is handed to the drives only when its last character has left the wire: until then a
later transmission may still garble it (a drive acts on a frame only once its CRC is in).
Without wire time (`--no-wire-time`) a frame takes no time on the wire, and nothing collides.

Every 06H write the drives got whole (its CRC good, nothing garbled it) is recorded with the
master that sent it (`writes`, the `writes` control command; each master's count in `stats`):
what a takeover test checks a write against (carried out at most once, and by one master).
"""

from __future__ import annotations

import contextlib
import os
import struct
from collections.abc import Iterable
from dataclasses import dataclass, replace
from typing import Any

from gateway.instruments.simulator.endpoint import Endpoint
from gateway.instruments.simulator.framing import ReceivedFrame, RequestAssembler

KEEP_ON_AIR_S = 1.0
"""How long a transmission is remembered after it ended, to compare later ones with."""
WRITE_SINGLE = 0x06
WRITE_SINGLE_LENGTH = 8
"""Address, 06H, register, value, CRC."""


@dataclass(slots=True)
class Transmission:
    """One master's frame on the wire, from `start` to `end` (the line's clock)."""

    master: int
    frame: ReceivedFrame
    start: float
    end: float
    garbled: bool = False
    handed: bool = False
    """Handed to the drives (its end has passed): kept a while to compare later ones with."""


class SharedWire:
    """The masters' side of one simulated line: their ports, what each transmitted, and what
    collided."""

    def __init__(self, masters: int, silence_s: float) -> None:
        if masters < 2:
            raise ValueError("a shared wire has two masters or more")
        self.count = masters
        self.endpoints: list[Endpoint] = []
        self._silence_s = silence_s
        self._assemblers = [RequestAssembler(silence_s) for _ in range(masters)]
        self._sent_until = [0.0] * masters
        """When each master's UART is free again (its last frame's end on the wire)."""
        self._on_air: list[Transmission] = []
        """Transmissions not yet handed to the drives, and those ended less than
        `KEEP_ON_AIR_S` ago."""
        self.frames = [0] * masters
        self.sent_bytes = [0] * masters
        self.collided = [0] * masters
        self.collisions = 0
        self.writes: list[tuple[int, int, int, int]] = []
        """Each 06H write the drives got whole: (master from 1, unit, register, value)."""
        self.written = [0] * masters
        self.unplugged: set[int] = set()
        """Masters whose adapter was pulled out (`unplug`), from 0."""

    # ----------------------------------------------------------------- ports

    def open(self) -> list[Endpoint]:
        """A pty for every master (all or none)."""
        opened: list[Endpoint] = []
        try:
            for _ in range(self.count):
                opened.append(Endpoint.open_pty())
        except BaseException:
            for endpoint in opened:
                endpoint.close()
            raise
        self.endpoints = opened
        self.unplugged.clear()
        return opened

    def close(self) -> None:
        for endpoint in self.endpoints:
            endpoint.close()
        self.endpoints = []
        self._assemblers = [RequestAssembler(self._silence_s) for _ in range(self.count)]
        self._on_air.clear()

    def unplug(self, master: int) -> None:
        """`master`'s adapter pulled out (from 0): its pty goes away (the gateway's open port
        fails, and its path is gone), the other masters stay on the line."""
        if not 0 <= master < len(self.endpoints):
            raise ValueError(f"no master {master + 1}: there are {len(self.endpoints)}")
        if master not in self.unplugged:
            self.unplugged.add(master)
            self.endpoints[master].close()

    @property
    def paths(self) -> list[str]:
        return [endpoint.path for endpoint in self.endpoints]

    def fds(self) -> list[int]:
        return [e.fd for i, e in enumerate(self.endpoints) if i not in self.unplugged]

    def master_of(self, fd: int) -> int | None:
        for index, endpoint in enumerate(self.endpoints):
            if endpoint.fd == fd:
                return index
        return None

    def relay(self, master: int, data: bytes) -> None:
        """Every other master hears what `master` transmits."""
        for index, endpoint in enumerate(self.endpoints):
            if index != master and index not in self.unplugged:
                with contextlib.suppress(OSError):  # a full or closed port: it hears nothing
                    os.write(endpoint.fd, data)

    def write_all(self, data: bytes) -> bool:
        """What a drive transmits reaches every master; True if one master at least got it."""
        written = False
        for index, endpoint in enumerate(self.endpoints):
            if index in self.unplugged:
                continue
            with contextlib.suppress(OSError):
                os.write(endpoint.fd, data)
                written = True
        return written

    # ----------------------------------------------------------------- frames

    def feed(self, master: int, data: bytes, at: float) -> list[ReceivedFrame]:
        """Bytes from `master` that arrived at `at`; the frames they complete."""
        self.sent_bytes[master] += len(data)
        return self._assemblers[master].feed(data, at)

    def on_silence(self, now: float) -> list[tuple[int, ReceivedFrame]]:
        """Frames (or garbage) that a silence up to `now` ends, by master."""
        return [
            (index, frame)
            for index, assembler in enumerate(self._assemblers)
            for frame in assembler.on_silence(now)
        ]

    def silence_deadline(self) -> float | None:
        deadlines = [a.silence_deadline() for a in self._assemblers]
        known = [d for d in deadlines if d is not None]
        return min(known) if known else None

    def transmit(
        self,
        master: int,
        frame: ReceivedFrame,
        character_s: float,
        replies: Iterable[tuple[float, float]],
    ) -> Transmission:
        """`master`'s frame goes on the wire: what it collides with is garbled with it (other
        masters' frames here; the drives' `replies`, (start, end) each, by the caller, who is
        told by `garbled`)."""
        start = max(frame.first_byte_at, self._sent_until[master])
        end = max(start + len(frame.data) * character_s, frame.last_byte_at)
        self._sent_until[master] = end
        this = Transmission(master, frame, start, end)
        self.frames[master] += 1
        for other in self._on_air:
            if other.master != master and other.start < end and start < other.end:
                self._collide(this, other)
        if any(begin < end and start < finish for begin, finish in replies):
            if not this.garbled:
                self.collisions += 1
                self.collided[master] += 1
            this.garbled = True
        self._on_air.append(this)
        return this

    def _collide(self, this: Transmission, other: Transmission) -> None:
        self.collisions += 1
        for each in (this, other):
            self.collided[each.master] += 1
            each.garbled = True

    def next_due(self) -> float | None:
        """When the next frame on the air has left the wire (handed to the drives then)."""
        waiting = [t.end for t in self._on_air if not t.handed]
        return min(waiting) if waiting else None

    def released(self, now: float) -> list[ReceivedFrame]:
        """The frames whose last character has left the wire by `now`, in order, as the
        drives see them: a garbled one fails its CRC."""
        done = sorted(
            (t for t in self._on_air if t.end <= now and not t.handed), key=lambda t: t.end
        )
        out = []
        for transmission in done:
            frame = transmission.frame
            out.append(replace(frame, valid=False) if transmission.garbled else frame)
            transmission.handed = True
            if frame.valid and not transmission.garbled:
                self._note_write(transmission.master, frame.data)
        forget = now - KEEP_ON_AIR_S
        self._on_air = [t for t in self._on_air if not t.handed or t.end > forget]
        return out

    def _note_write(self, master: int, data: bytes) -> None:
        if len(data) == WRITE_SINGLE_LENGTH and data[1] == WRITE_SINGLE:
            register, value = struct.unpack(">HH", data[2:6])
            self.writes.append((master + 1, data[0], register, value))
            self.written[master] += 1

    def stats(self) -> dict[str, Any]:
        return {
            "collisions": self.collisions,
            "masters": [
                {
                    "path": path,
                    "frames": self.frames[index],
                    "bytes": self.sent_bytes[index],
                    "collisions": self.collided[index],
                    "writes": self.written[index],
                }
                for index, path in enumerate(self.paths or [""] * self.count)
            ],
        }
