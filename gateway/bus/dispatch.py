"""The bus's side of each gap's end: which transaction goes next, and for how long it may wait.

The bus's coroutine hands its line a `Dispatch` (a `gateway.bus.line_user.LineUser`): in the
wake-up that ends each inter-frame gap the line asks it for the next frame (`pick`), takes the
reply window of what it chose (`reply_timeout_s`), and tells it of a reply the reader callback
finished (`replied`, which ends the transaction there). With nothing queued, it says how long the
line may wait idle before the bus looks at its probes again (`idle_for`).
"""

from __future__ import annotations

import time
from enum import StrEnum

from gateway.bus.carrier import Carrier
from gateway.bus.exchange import Sending
from gateway.bus.health import HealthTracker
from gateway.bus.observers import Outcome, give
from gateway.bus.probes import due_probes
from gateway.bus.queue import RequestQueue
from gateway.bus.stats import BusStats
from gateway.errors import DriveOffline, GatewayError
from gateway.modbus.rtu import BROADCAST_ADDRESS, build_frame

IDLE_WAKE_S = 0.5
"""With nothing queued, the bus still wakes this often to see whether a probe is due."""


class BusState(StrEnum):
    OPENING = "opening"
    OPEN = "open"
    REOPENING = "reopening"
    CLOSED = "closed"


# Enum members read per transaction, as module globals (see `gateway.bus.queue`: a member read
# costs ~950 instructions on Python 3.11, a global ~45).
_OPEN, _CLOSED = BusState.OPEN, BusState.CLOSED


class Dispatch:
    """Chooses the bus's next transaction at each gap's end (`LineUser` of its line)."""

    __slots__ = (
        "_carrier",
        "_health",
        "_late_replies",
        "_queue",
        "_retries",
        "_stats",
        "_timeout_s",
        "name",
        "reply_timeout_s",
        "state",
    )

    def __init__(
        self,
        name: str,
        queue: RequestQueue,
        carrier: Carrier,
        health: HealthTracker,
        stats: BusStats,
        timeout_s: float,
        retries: int,
    ) -> None:
        self.name = name
        self.state = BusState.OPENING
        """What the line is (`Bus.state` shows it): only an open line is picked for."""
        self.reply_timeout_s: float | None = None
        self._queue = queue
        self._carrier = carrier
        self._late_replies = carrier.late_replies
        self._health = health
        self._stats = stats
        self._timeout_s = timeout_s
        self._retries = retries

    def pick(self) -> bytes | None:
        """Take the best transaction queued now and return its frame; None if there is none."""
        # The first pick after a reply is the gap's end: what it finds waited for the line, and
        # the silence before it, beyond the gap, is the gateway's own (`Carrier.sent`). That
        # includes a request queued during the gap (clients answered together ask again
        # together) and one queued after the gap had ended but before the gateway woke for it
        # (it waited for the gateway: leaving it out would hide the late wake-ups). When that
        # pick finds nothing, the line goes idle and the next request waited for nobody (a
        # client's think time). After a broadcast or a timeout there is no reply to count from.
        carrier = self._carrier
        reply_heard_at = carrier.reply_heard_at
        carrier.reply_heard_at = 0.0
        self.reply_timeout_s = None
        if self.state is _CLOSED:
            return None
        health = self._health
        if health.offline_count:  # a busy line must still find a drive is back
            self.queue_due_probes()
        queue = self._queue
        while (transaction := queue.get_nowait()) is not None:
            probe = transaction.probe
            if not probe and not transaction.wanted():
                continue  # every waiter gone (clients disconnected): no bus time for it
            address = transaction.address
            if (
                address != BROADCAST_ADDRESS
                and not probe
                and health.offline_count  # none offline (the usual case): no call
                and health.is_offline(address)
            ):  # went offline while this waited: 0BH at once, without bus time
                self._stats.offline_rejected += 1
                give(transaction, DriveOffline(f"drive {address} on {self.name} is offline"))
                continue
            carrier.carrying = transaction  # before anything can fail: it must be answered
            carrier.back_to_back = reply_heard_at != 0.0
            if probe or address in self._late_replies.owing:
                # A marker first (a probe is one): `Carrier.carry` reads its answer, the frames
                # before it set aside, then sends the request (`gateway.bus.late_replies`).
                carrier.marker_sent = marker = self._late_replies.marker(address)
                return marker
            if address != BROADCAST_ADDRESS:  # a broadcast has no reply to hold its caller for
                self.reply_timeout_s = transaction.timeout_s
            return transaction.frame or build_frame(address, transaction.pdu)
        return None

    def replied(self, sending: Sending, pdu: bytes, heard_at: float) -> None:
        """The first attempt of the transaction carried has its whole and valid reply, heard as
        the line's reader callback finished it (`GapKeeper.heard`): the transaction ends here,
        through the calls the carrier's `carry` and the bus's coroutine end it with, without
        the coroutine (one pass of the event loop less per transaction). A timeout, a bad,
        partial or late reply, retries: those go the coroutine's way. Never a broadcast."""
        carrier = self._carrier
        transaction = carrier.carrying
        assert transaction is not None  # the line holds a reply to what was picked
        started = sending.started
        outcome: Outcome
        try:
            address = transaction.address
            drive = carrier.drive_stats.get(address) or carrier.drive(address)
            carrier.sent(drive, sending.frame, sending)
            drive.line_s += time.monotonic() - started
            outcome = carrier.attempt_answered(
                transaction, 0, started, pdu, sending.gap_s, heard_at - started, heard_at, drive
            )
        except Exception as exc:  # a bug costs this one request, never the line
            outcome = carrier.bug(transaction, exc)
        carrier.finish(transaction, outcome, started)

    def idle_for(self) -> float | None:
        """With nothing queued at a gap's end: how long the line may wait, idle, for a request
        (`Bus._wake` sends one queued meanwhile at once); None once the bus is closing."""
        if self.state is _CLOSED:
            return None
        next_probe = self._health.next_probe_at()
        wait = IDLE_WAKE_S if next_probe is None else next_probe - time.monotonic()
        return min(max(wait, 0.001), IDLE_WAKE_S)

    def queue_due_probes(self) -> None:
        """Queue a probe for each offline drive whose backoff is over (`due_probes`)."""
        if not self._health.any_offline or self.state is not _OPEN:
            return
        for probe in due_probes(self._health, self._timeout_s, self._retries, time.monotonic()):
            try:
                self._queue.put(probe)
            except GatewayError:
                return
