"""A `LineUser` for the line's own tests, made of the callables each test gives."""

from __future__ import annotations

from collections.abc import Callable

from gateway.bus.exchange import Sending
from gateway.bus.line import SerialLine
from gateway.bus.line_user import LineUser


class Callables:
    """Picks with `pick`; after a frame, its reply window from `reply_within` (the bus's
    `Dispatch` sets it as it picks); tells `replied`; idles for `idle_for`."""

    def __init__(
        self,
        pick: Callable[[], bytes | None],
        reply_within: Callable[[], float | None] | None = None,
        replied: Callable[[Sending, bytes, float], None] | None = None,
        idle_for: Callable[[], float | None] | None = None,
    ) -> None:
        self._pick, self._reply_within = pick, reply_within
        self._replied, self._idle_for = replied, idle_for
        self.reply_timeout_s: float | None = None

    def pick(self) -> bytes | None:
        frame = self._pick()
        within = self._reply_within
        self.reply_timeout_s = within() if frame is not None and within is not None else None
        return frame

    def replied(self, sending: Sending, pdu: bytes, heard_at: float) -> None:
        assert self._replied is not None, "held until a reply with nobody to tell"
        self._replied(sending, pdu, heard_at)

    def idle_for(self) -> float | None:
        return None if self._idle_for is None else self._idle_for()


async def send_after_gap(
    line: SerialLine,
    pick: Callable[[], bytes | None],
    reply_within: Callable[[], float | None] | None = None,
    replied: Callable[[Sending, bytes, float], None] | None = None,
    idle_for: Callable[[], float | None] | None = None,
) -> Sending | None:
    """`line.send_after_gap` for a user made of these callables."""
    user: LineUser = Callables(pick, reply_within, replied, idle_for)
    return await line.send_after_gap(user)
