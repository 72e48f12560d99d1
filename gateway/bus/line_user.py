"""Who sends on a line through its gap keeper: the one interface between the bus and the wire.

`GapKeeper.send_after_gap` takes a `LineUser` and, in the wake-up that ends each inter-frame
gap, asks it for the frame to send (`pick`); right after, it reads how long that frame's drive
has to answer (`reply_timeout_s`) and holds its caller until the reply. A reply whole and valid
as the reader callback takes it in is told to the user there (`replied`), which ends the
transaction without a pass of the caller's coroutine. With nothing to pick, the user says how
long the line may wait idle for a request (`idle_for`).

The bus's user is its `Dispatch` (`gateway.bus.dispatch`); a marker, a probe's or one bringing a
drive back in step, goes as a `OneFrame`, whose answer its caller reads itself.
"""

from __future__ import annotations

from typing import Protocol

from gateway.bus.exchange import Sending


class LineUser(Protocol):
    """What `send_after_gap` asks at a gap's end, and tells of a reply it finished itself."""

    @property
    def reply_timeout_s(self) -> float | None:
        """For the frame `pick` just gave: how long its drive has to answer, the caller held
        until the reply's first bytes or then (None: no reply, or one the caller reads itself).
        An attribute `pick` sets as it chooses: one read per transaction, not another call."""
        ...

    def pick(self) -> bytes | None:
        """The frame to send now (None: nothing to send)."""
        ...

    def replied(self, sending: Sending, pdu: bytes, heard_at: float) -> None:
        """The attempt `sending` has its whole and valid reply `pdu`, whose last byte was heard
        at `heard_at`: taken in by the port's reader callback, which tells it here."""
        ...

    def idle_for(self) -> float | None:
        """`pick` had nothing: how long the caller may stay held with the line idle for a
        request (`GapKeeper.kick` sends one queued meanwhile); None: not at all."""
        ...


class OneFrame:
    """A `LineUser` that sends one frame and reads its answer itself (`SerialLine.finish`): a
    marker, a frame of the line's own tests and tools."""

    __slots__ = ("frame",)

    reply_timeout_s: float | None = None

    def __init__(self, frame: bytes) -> None:
        self.frame = frame

    def pick(self) -> bytes:
        return self.frame

    def replied(self, sending: Sending, pdu: bytes, heard_at: float) -> None:
        raise AssertionError("a OneFrame's caller is never held until its reply")

    def idle_for(self) -> None:
        return None
