"""The role machine: which of the two boxes on a line is its master, and the never-two rule.

    standby    the ports open only to listen (`LineListener`), nothing transmitted; the poller
               and the MQTT bridge stopped; Modbus-TCP answered 0AH (`StandbyRefusal`)
    listening  asked to be active (`invt-gateway role active`, or `role: active` at start), still
               off the line: it takes the line once every line has been heard silent for
               `silence_s + hold_off_s` (a live master polls all the time); another master's
               frames heard keep it here
    active     the buses run, the poller and the bridge with them; every read from a port is
               watched (`ActiveWatch`): a request it did not send is another master's, and the
               line is silenced at once, in that very reader callback (every bus closed, every
               port's write gate closed: no frame more, whoever would write it), said loudly
               (log, event, metric, /health); then it leaves the line and listens again, as
               asked, with a random back-off of up to `silence_s` beyond its silence, so that
               two boxes that took the line at once (the one race listening can't close) don't
               take it at once again

A box asked active that has heard another master for `LATCH_S` while it listened (a cut between
the boxes: both VRRP MASTER) gives the virtual address up: the latch (`SplitLatch`) says it
unfit, in the fault file and `role status`, until no other master has been heard for
`silence_s`.

Who asks is the coordinator's business (Keepalived's notify script: `config/
invt-gateway-notify.sh`); the machine makes sure that whatever it is asked, and whatever the
other box does, this box transmits only on a line it has heard silent, and stops when it hears
another master.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import random
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import Any, Final, Protocol

from gateway.bus import Bus
from gateway.bus.line_settings import LineSettings
from gateway.poller.drive_state import iso_time
from gateway.redundancy.fault_file import FaultFile
from gateway.redundancy.frames import Frame, Kind
from gateway.redundancy.latch import LATCH_S, SplitLatch
from gateway.redundancy.listener import LineListener
from gateway.redundancy.peer_config import PeerConfig
from gateway.redundancy.watch import ActiveWatch
from gateway.settings.redundancy import RedundancySettings
from gateway.store import EventStore, EventType

log = logging.getLogger(__name__)

LOOK_AGAIN_S: Final = 0.25
"""While listening, how often the silence is looked at again without news (a port opened);
while active, how often the ports are."""
PORTLESS_S: Final = 1.0
"""How long every one of this box's lines may have no port open (its USB adapter unplugged, a
device server gone) before the box says it can't be their master: an active one leaves the
lines, the fault file says 1 (`FaultFile`: Keepalived's instance FAULT at once, the virtual
address moved to the other box a fraction of `advert_int` later) and `role status` fails (the
track script, the slower way). Longer than a glitch the port gets over by itself: the bus opens
it again at once and again half a second later (a listener every `REOPEN_S`); short enough
that the other box is told, and MASTER, before the line's silence it must hear anyway
(`silence_ms`, 2.4 s with the INVT profiles' defaults) is over."""


class Role(StrEnum):
    STANDBY = "standby"
    LISTENING = "listening"
    ACTIVE = "active"


ASKABLE: Final = (Role.ACTIVE.value, Role.STANDBY.value)


class LineOwner(Protocol):
    """The application's side of a role change."""

    async def take_line(self, hook: Callable[[Bus], None]) -> None:
        """Fresh buses open their ports and serve (each given to `hook` before it runs), the
        poller and the MQTT bridge start."""

    async def leave_line(self, reason: str) -> None:
        """The buses close (the transaction on a wire finishes, unless silenced), the poller
        and the MQTT bridge stop."""


@dataclass(frozen=True, slots=True)
class RoleChange:
    role: Role
    reason: str
    at: float
    """Wall-clock time (epoch seconds)."""

    def as_json(self) -> dict[str, Any]:
        return {"role": self.role.value, "reason": self.reason, "at": iso_time(self.at)}


class Redundancy:
    """One gateway's role on its lines, from start to stop (`run`, a service task)."""

    def __init__(
        self,
        settings: RedundancySettings,
        lines: Sequence[LineSettings],
        owner: LineOwner,
        events: EventStore | None = None,
    ) -> None:
        self.settings = settings
        self.owner = owner
        self.events = events
        self.role = Role.STANDBY
        self.asked = Role.STANDBY
        self.last_change = RoleChange(Role.STANDBY, "started", time.time())
        self.changes: dict[Role, int] = dict.fromkeys(Role, 0)
        """Changes into each role, since start."""
        self.foreign_frames = 0
        """Another master's frames heard while this gateway was active."""
        self.last_foreign: dict[str, Any] | None = None
        self.last_takeover_s: float | None = None
        """From `role active` (or the start) to the line taken, the last time."""
        self._listeners = [LineListener(line, self._wake, self._heard) for line in lines]
        self._latch = SplitLatch(settings.silence_s)
        """Another master heard while asked active: unfit to hold the virtual address."""
        self._listening_since: float | None = None
        """Since when this box has been `listening` (asked active, off the line)."""
        self._fault_file = FaultFile(settings.fault_file) if settings.fault_file else None
        self._watches: list[ActiveWatch] = []
        self._asked_at = time.monotonic()
        self._back_off_s = 0.0
        """Silence waited beyond `listen_s` after a demotion (random, up to `silence_s`)."""
        self._portless_since: float | None = None
        """Since when no port of this box's lines has been open (`PORTLESS_S`)."""
        self._taking = False
        """The lines being taken (`_take`): the listeners stopped, the buses opening."""
        self._silenced: str | None = None
        """Why the line was silenced (another master heard), until this gateway has left it."""
        self._changed: asyncio.Event | None = None
        self.listeners: list[Callable[[], None]] = []
        """Told after each role change (the MQTT role announcement)."""
        self.peer_config: PeerConfig | None = None
        """With MQTT, the other box's configuration compared with this one's (its status)."""

    # -- asked on the control socket ------------------------------------------------------------

    def ask(self, wanted: str) -> list[str]:
        """`role active`, `role standby` or `role status`: the answer's lines (`ok: ...`)."""
        if wanted == "status":
            status = self.status()
            answer = [json.dumps(status, sort_keys=True)]
            portless_s = self._portless_for(time.monotonic())
            # `unfit:` makes the command exit 1, and the track script fail. Not for the latch
            # when the fault file tells Keepalived (at once, both ways): a failing script would
            # hold the box in FAULT for its `rise` once the other master is gone.
            latch_told = self._latch.latched and self._fault_file is not None
            if status["unfit"] is not None and (not latch_told or self._portless(portless_s)):
                answer.append(f"unfit: {status['unfit']}")
            return answer
        if wanted not in ASKABLE:
            return [f"refused: unknown role {wanted!r} (active, standby or status)"]
        role = Role(wanted)
        if role is not self.asked:
            self.asked, self._asked_at, self._back_off_s = role, time.monotonic(), 0.0
            log.warning("redundancy: asked to be %s (was %s)", role.value, self.role.value)
            if role is Role.ACTIVE and self.role is Role.STANDBY:
                self._set_role(Role.LISTENING, "asked to be active: listening to the line first")
            self._wake()
        return [f"ok: {wanted}: {self.describe()}"]

    def describe(self) -> str:
        """The role in a few words, for the answer and the log."""
        if self.role is Role.ACTIVE:
            return "active: this gateway is the line's master"
        if self.role is Role.LISTENING:
            return (
                f"listening: takes the line once it has been silent "
                f"{self.settings.listen_s + self._back_off_s:.1f} s"
            )
        return "standby: listening only, never transmitting"

    def status(self) -> dict[str, Any]:
        """For `role status`, /health and the console."""
        now = time.monotonic()
        heard = [listener.ear for listener in self._listeners]
        status: dict[str, Any] = {
            "box": self.settings.box,
            "role": self.role.value,
            "asked": self.asked.value,
            "peer": self.settings.peer,
            "notify": self.settings.notify,
            "last_change": self.last_change.as_json(),
            "silence_s": round(self.settings.silence_s, 3),
            "hold_off_s": round(self.settings.hold_off_s, 3),
            "takeovers": self.changes[Role.ACTIVE],
            "last_takeover_s": None
            if self.last_takeover_s is None
            else round(self.last_takeover_s, 3),
            "foreign_frames": self.foreign_frames,
            "last_foreign": self.last_foreign,
        }
        portless_s = self._portless_for(now)
        status["portless_s"] = None if portless_s is None else round(portless_s, 1)
        status["unfit"] = self._unfit(now, portless_s)
        status["fit"] = status["unfit"] is None
        if self.role is not Role.ACTIVE:
            silent = [lsn.silent_for(now) for lsn in self._listeners if lsn.open]
            status["line_silent_s"] = round(min(silent), 3) if silent else None
            # A port it can't open is a line it can't hear: it could not take that one over
            # knowing it silent (/health says degraded).
            status["deaf"] = [lsn.settings.name for lsn in self._listeners if not lsn.open]
            status["heard_requests"] = sum(ear.requests for ear in heard)
            status["heard_replies"] = sum(ear.replies for ear in heard)
            hearing_s = self._latch.hearing_for(now)
            status["another_master_heard_s"] = None if hearing_s is None else round(hearing_s, 1)
        if self.peer_config is not None:
            status["peer_config"] = self.peer_config.status()
        return status

    @property
    def fit(self) -> bool:
        """This box can be the line's master and hold the virtual address (`status`'s)."""
        now = time.monotonic()
        return self._unfit(now, self._portless_for(now)) is None

    @property
    def serving(self) -> bool:
        """This gateway may send to its drives (and answer for them)."""
        return self.role is Role.ACTIVE and self._silenced is None

    # -- the task -------------------------------------------------------------------------------

    async def run(self) -> None:
        self._changed = asyncio.Event()
        for listener in self._listeners:
            listener.start()
        if self.settings.start_role == Role.ACTIVE.value:
            self.ask(Role.ACTIVE.value)
        else:
            log.warning("redundancy: standby: listening to the line, never transmitting")
        try:
            while True:
                await self._step()
        finally:
            if self._fault_file is not None:  # Keepalived moves the address now, not later
                self._fault_file.tell(False, "the gateway is stopping")
            for listener in self._listeners:
                await listener.stop()
            for watch in self._watches:
                watch.close()

    async def _step(self) -> None:
        now = time.monotonic()
        self._look_latch(now)
        portless_s = self._portless_for(now)
        portless = self._portless(portless_s)  # unfit for the line (the latch: for the address)
        if self._fault_file is not None:
            unfit = self._unfit(now, portless_s)
            self._fault_file.tell(unfit is None, unfit or "")
        # Looked at again when the ports have been gone PORTLESS_S (a lost port wakes it).
        look_again_s = LOOK_AGAIN_S
        if portless_s is not None and not portless:
            look_again_s = min(look_again_s, PORTLESS_S - portless_s + 0.001)
        if self.role is Role.ACTIVE:
            if self._silenced is None and portless:
                self._silenced = self._portless_reason(portless_s or 0.0)
                log.error("redundancy: %s: leaving the line", self._silenced)
            if self._silenced is not None or self.asked is not Role.ACTIVE:
                await self._leave()
            else:
                await self._news(look_again_s)
            return
        if self.asked is not Role.ACTIVE:
            # Listening, and asked to be standby after all: off the line it stays.
            self._set_role(Role.STANDBY, "asked to be standby")
            await self._news(look_again_s)
            return
        left = self._silence_left(time.monotonic())
        if left is not None and left <= 0:
            await self._take()
            return
        await self._news(look_again_s if left is None else min(left, look_again_s))

    def _portless_for(self, now: float) -> float | None:
        """How long no port of this box's lines has been open (the active's buses', the
        listeners' otherwise); None while one is."""
        if self._taking:
            open_now = True  # between the listeners and the buses: the parts start
        elif self.role is Role.ACTIVE:
            open_now = any(watch.bus.line.is_open for watch in self._watches)
        else:
            open_now = any(listener.open for listener in self._listeners)
        if open_now:
            self._portless_since = None
            return None
        if self._portless_since is None:
            self._portless_since = now
        return now - self._portless_since

    def _unfit(self, now: float, portless_s: float | None) -> str | None:
        """Why this box can't be the line's master, or hold the virtual address; None: it
        can."""
        if portless_s is not None and self._portless(portless_s):
            return self._portless_reason(portless_s)
        if self._latch.latched:
            hearing_s = self._latch.hearing_for(now) or 0.0
            return (
                "another master heard while this box was asked to be active (a cut between "
                f"the boxes?), and for {hearing_s:.1f} s now: this box gives the virtual "
                f"address up until no master is heard for {self.settings.silence_s:.1f} s"
            )
        return None

    @staticmethod
    def _portless(portless_s: float | None) -> bool:
        """No port open for longer than `PORTLESS_S`: this box can't be the line's master."""
        return portless_s is not None and portless_s > PORTLESS_S

    def _heard(self, frame: Frame) -> None:
        """A frame a listener heard: a request (drives send none) is another master's."""
        if frame.kind is not Kind.REPLY:
            # Its end: the last byte any line heard (as the silence before a takeover counts).
            self._latch.heard(max(listener.ear.heard_at for listener in self._listeners))

    def _look_latch(self, now: float) -> None:
        """The latch set (another master heard `LATCH_S` while listening) or cleared (none
        heard for `silence_s`): said in the log and an event; the fault file follows."""
        changed = self._latch.look(now, self._listening_since)
        if changed is None:
            return
        if changed:
            reason = self._unfit(now, None)
            log.warning("redundancy: %s", reason)
            heard_s = round(self._latch.hearing_for(now) or LATCH_S, 1)
            data = {"role": self.role.value, "heard_s": heard_s, "reason": reason}
            event = EventType.ANOTHER_MASTER_HEARD
        elif self._latch.on_trial:
            # Another master still heard: no event (nothing is gone); a healed link keeps the
            # box BACKUP now, a cut that goes on latches it again (`gateway.redundancy.latch`).
            log.info(
                "redundancy: another master still heard after %.0f s unfit: this box may hold "
                "the virtual address again, on trial (the link between the boxes healed?)",
                self._latch.retry_s,
            )
            return
        else:
            reason = (
                f"no other master heard for {self.settings.silence_s:.1f} s: this box can hold "
                "the virtual address again"
            )
            log.info("redundancy: %s", reason)
            data = {"role": self.role.value, "reason": reason}
            event = EventType.ANOTHER_MASTER_GONE
        if self.events is not None:
            self.events.record(event, {**data, "peer": self.settings.peer})

    @staticmethod
    def _portless_reason(portless_s: float) -> str:
        return (
            f"no port open on any line for {portless_s:.1f} s (its adapter unplugged?): "
            "this box can't be the line's master"
        )

    def _silence_left(self, now: float) -> float | None:
        """How much longer the lines must stay silent before this gateway takes them; None
        while no port is open to hear them (its silence would prove nothing)."""
        heard = [listener.silent_for(now) for listener in self._listeners if listener.open]
        if not heard:
            return None
        return self.settings.listen_s + self._back_off_s - min(heard)

    async def _news(self, timeout_s: float | None) -> None:
        changed = self._changed
        assert changed is not None
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(changed.wait(), timeout_s)
        changed.clear()

    def _wake(self) -> None:
        if self._changed is not None:
            self._changed.set()

    async def _take(self) -> None:
        """The lines have been silent long enough: the buses take them."""
        silent_s = self.settings.listen_s + self._back_off_s
        self._taking = True
        try:
            for listener in self._listeners:
                await listener.stop()
            self._silenced = None
            await self.owner.take_line(self.watch)
        finally:
            self._taking = False
        self.last_takeover_s = time.monotonic() - self._asked_at
        self._set_role(Role.ACTIVE, f"the line was silent {silent_s:.1f} s: taken")

    def watch(self, bus: Bus) -> None:
        """Watch `bus`'s line for another master's frames from its port's opening (before it
        runs): the buses taken, and one a reload reopens in place of another of its name."""
        for old in [w for w in self._watches if w.bus.name == bus.name]:
            old.close()
            self._watches.remove(old)
        self._watches.append(ActiveWatch(bus, self.foreign_master, self._wake))

    def foreign_master(self, bus: str, frame: bytes) -> None:
        """Another master's frame, heard by an active bus (in its port's reader callback):
        every line silenced now, before anything else runs; the role follows (`_leave`)."""
        self.foreign_frames += 1
        if self._silenced is not None:
            return  # already silenced: counted
        reason = f"another master is on the line: its request {frame.hex(' ')} heard on bus {bus}"
        self._silenced = reason
        for watch in self._watches:
            watch.gate.close(reason)  # no byte more through its port, whoever writes
            watch.bus.close(f"stopped: {reason}")
        self.last_foreign = {"bus": bus, "frame": frame.hex(" "), "at": iso_time(time.time())}
        log.critical("redundancy: %s: transmitting stopped, leaving the line", reason)
        if self.events is not None:
            self.events.record(EventType.FOREIGN_MASTER, {"bus": bus, "frame": frame.hex(" ")})
        self._wake()

    async def _leave(self) -> None:
        silenced = self._silenced
        reason = silenced or "asked to be standby"
        await self.owner.leave_line(reason)
        for watch in self._watches:
            watch.close()
        self._watches = []
        for listener in self._listeners:
            listener.start()
        self._silenced = None
        if silenced is not None and self.asked is Role.ACTIVE:
            # Still asked to be active: listen again, with a back-off the other box won't share.
            self._back_off_s = random.uniform(0.0, self.settings.silence_s)
            self._asked_at = time.monotonic()  # the next takeover's time counts from here
            self._set_role(Role.LISTENING, f"{silenced}: off the line, listening")
        else:
            self._set_role(Role.STANDBY, reason)

    def _set_role(self, role: Role, reason: str) -> None:
        if role is self.role:
            return
        self.role = role
        self.changes[role] += 1
        self._listening_since = time.monotonic() if role is Role.LISTENING else None
        self.last_change = RoleChange(role, reason, time.time())
        log.warning("redundancy: %s (%s)", self.describe(), reason)
        if self.events is not None:
            data = {"role": role.value, "reason": reason, "peer": self.settings.peer}
            self.events.record(EventType.ROLE_CHANGED, data)
        for listener in self.listeners:
            try:
                listener()
            except Exception:  # a listener's bug must not keep the role from changing
                log.exception("redundancy: role listener failed")
