"""The latch that gives the virtual address up in a cut between the two boxes (issue 48).

A cut that leaves both boxes reaching SCADA (VRRP's adverts lost between them, both links up)
makes both Keepalived MASTER, and both notify scripts ask `role active`. The line stays safe:
the box asked active hears the other's polls and stays `listening`. But it holds the virtual
address too, and its gratuitous ARPs (sent as it became MASTER) drew SCADA to it: every request
answered 0AH for as long as the cut lasts.

So a box asked to be active that has heard another master's requests (drives never send any)
for `LATCH_S`, all the while it listened, is **unfit to hold the address**: the latch is set,
the fault file says 1 (Keepalived's instance FAULT at once, the address dropped; its notify
asks `role standby`), and the other box, MASTER all along, draws SCADA back with its periodic
gratuitous ARPs (`garp_master_refresh` in config/keepalived.conf).

The latch holds while another master is heard, whatever this box's role: cleared as soon as
the box is standby, its Keepalived would go BACKUP, hear no adverts (the cut goes on), be MASTER
again, and this box would latch again `LATCH_S` later: a loop that hands SCADA to the wrong box
every few seconds. It clears once no request has been heard for `silence_s` (the other master
gone): the box is fit again and may be the line's master.

Held while the other master is heard, the latch would also outlast the cut: once the link is
back this box stays FAULT (a standby still, but one that must hear the line silent and then
wait out VRRP before it takes over: ~4.4 s instead of ~2.5 s with the INVT defaults). So every
`RETRY_S` it is let go on trial: Keepalived goes BACKUP; with the link back it hears the
MASTER's adverts and stays BACKUP (a plain standby again); with the cut still there it is MASTER
again in a second and a half, asked active, and latched again `LATCH_S` later: a few seconds
of 0AH for SCADA once every `RETRY_S` while the cut lasts.
"""

from __future__ import annotations

from typing import Final

LATCH_S: Final = 3.0
"""How long a box asked active may hear another master before it gives the address up. Longer
than any overlap of two masters that is no cut: the moment VRRP moves the address (the old
master's notify script asking `role standby` and its gateway leaving the line: a fraction of a
second, a second or two on a loaded box), and an active that heard another master's request and
went back to listening while the other box's notify arrives. Not tied to `silence_s`: that
follows the poll interval, the overlap doesn't; and SCADA's outage in a cut is this bound
plus the other box's next gratuitous ARP, so it is kept short."""


RETRY_S: Final = 60.0
"""How long the latch holds another master heard before it is let go on trial (above): a
minute at most of the slower takeover after a cut has healed, against some 5 s of 0AH a minute
while it lasts."""


class SplitLatch:
    """Another master heard while asked to be active (`look`), told by request (`heard`).

    Times are `time.monotonic()` seconds."""

    def __init__(
        self, silence_s: float, bound_s: float = LATCH_S, retry_s: float = RETRY_S
    ) -> None:
        self.silence_s = silence_s
        self.bound_s = bound_s
        self.retry_s = retry_s
        self.heard_at: float | None = None
        """When another master's request was last heard (a listener's)."""
        self.heard_since: float | None = None
        """Since when requests have been heard with no silence of `silence_s` between them."""
        self.latched_at: float | None = None
        """When the latch was set (None: not set)."""
        self.on_trial = False
        """Its last clearing was a trial (`RETRY_S`), another master still heard."""

    def heard(self, now: float) -> None:
        """A request heard on a line this box listens to: another master's."""
        if self.heard_at is None or now - self.heard_at >= self.silence_s:
            self.heard_since = now
        self.heard_at = now

    def hearing_for(self, now: float) -> float | None:
        """How long another master has been heard without a silence of `silence_s`; None
        while it isn't."""
        if self.heard_at is None or self.heard_since is None:
            return None
        if now - self.heard_at >= self.silence_s:
            return None
        return now - self.heard_since

    @property
    def latched(self) -> bool:
        return self.latched_at is not None

    def look(self, now: float, listening_since: float | None) -> bool | None:
        """The latch's rule, looked at `now`; `listening_since`: since when this box has been
        asked active and listening (None: it isn't). True when it is set now, False when it is
        cleared now (`on_trial` says whether another master is still heard), None when nothing
        changed."""
        hearing_s = self.hearing_for(now)
        if self.latched_at is not None:
            # The line silent `silence_s` (the other master gone), or let go on trial.
            self.on_trial = hearing_s is not None
            if self.on_trial and now - self.latched_at < self.retry_s:
                return None
            self.latched_at = None
            return False
        if hearing_s is None or listening_since is None or self.heard_since is None:
            return None
        if now - max(self.heard_since, listening_since) >= self.bound_s:
            self.latched_at = now
            return True
        return None
