"""Which drives on a line answer, and when to try an offline one again.

A drive that stops answering costs a full response timeout (plus retries) for every request sent to
it; on a shared line that stalls every healthy drive too. After `offline_after` consecutive failed
transactions the drive is offline: its requests are answered 0x0B at once, without bus time, and a
single-attempt probe with growing, capped backoff finds out when it is back. A drive that has just
failed gets no retries until it answers again, so isolating it costs little bus time.
"""

from __future__ import annotations

import random
from dataclasses import dataclass

from gateway.backoff import Backoff


@dataclass(slots=True)
class DriveHealth:
    probes: Backoff
    """The waits between probes while offline (`gateway.backoff`)."""
    consecutive_failures: int = 0
    offline: bool = False
    next_probe_at: float = 0.0
    lost_with_line: bool = False
    """Offline because the port went, not because the drive fell silent."""


class HealthTracker:
    def __init__(
        self,
        offline_after: int,
        probe_initial_s: float,
        probe_max_s: float,
        rng: random.Random | None = None,
    ) -> None:
        self.offline_after = offline_after
        self.probe_initial_s = probe_initial_s
        self.probe_max_s = probe_max_s
        self._drives: dict[int, DriveHealth] = {}
        self._rng = rng or random.Random()
        self.offline_count = 0
        """How many drives are offline: none, and no probe can be due (asked per transaction)."""
        self.answering: set[int] = set()
        """Drives that answered their last transaction, with nothing reset since: for them
        `record_answer` has nothing to do, and the bus, asking per transaction, needs no call
        to find that out (a set lookup). Left by a failure (`record_failure`, `force_offline`)."""

    def _get(self, address: int) -> DriveHealth:
        health = self._drives.get(address)
        if health is None:
            probes = Backoff(self.probe_initial_s, self.probe_max_s, self._rng)
            health = self._drives[address] = DriveHealth(probes)
        return health

    @property
    def any_offline(self) -> bool:
        return self.offline_count > 0

    def is_offline(self, address: int) -> bool:
        health = self._drives.get(address)
        return health is not None and health.offline

    def is_suspect(self, address: int) -> bool:
        """Failed its last transaction: don't spend retries on it."""
        health = self._drives.get(address)
        return health is not None and health.consecutive_failures > 0

    def offline_addresses(self) -> list[int]:
        return [address for address, health in self._drives.items() if health.offline]

    def record_answer(self, address: int) -> bool:
        """The drive answered (any valid frame, exceptions too). True if it was offline."""
        health = self._drives.get(address)
        if (
            health is not None
            and not health.consecutive_failures
            and not health.offline
            and not health.lost_with_line
        ):
            # Nothing to reset: the drive answered last time too, or its health was made
            # without a failure (its probes' backoff was reset when it last came back, or
            # never moved). Now the bus needs no call for it (`answering`).
            self.answering.add(address)
            return False
        health = self._get(address)
        was_offline = health.offline
        if was_offline:
            self.offline_count -= 1
        health.consecutive_failures = 0
        health.offline = False
        health.probes.reset()
        health.lost_with_line = False
        self.answering.add(address)
        return was_offline

    def record_failure(self, address: int, now: float) -> bool:
        """A transaction got no valid reply. True if this made the drive go offline."""
        health = self._get(address)
        self.answering.discard(address)
        health.consecutive_failures += 1
        health.lost_with_line = False  # silent on a working line: from now on, a dead drive
        if health.offline:
            self._schedule_probe(health, now)
            return False
        if health.consecutive_failures >= self.offline_after:
            health.offline = True
            self.offline_count += 1
            health.probes.reset()
            self._schedule_probe(health, now)
            return True
        return False

    def known_addresses(self) -> list[int]:
        return list(self._drives)

    def force_offline(self, address: int, now: float) -> bool:
        """The line itself is gone (port lost). True if the drive was online until now."""
        health = self._get(address)
        if health.offline:
            return False
        self.answering.discard(address)
        health.offline = True
        self.offline_count += 1
        health.lost_with_line = True
        health.consecutive_failures = max(health.consecutive_failures, 1)
        health.probes.reset()
        self._schedule_probe(health, now)
        return True

    def line_back(self, now: float) -> list[int]:
        """The port is open again: the drives it took offline are worth a probe at once."""
        back = []
        for address, health in self._drives.items():
            if health.offline and health.lost_with_line:
                health.next_probe_at = now
                back.append(address)
        return back

    def lost_with_line(self, address: int) -> bool:
        """Offline only because the port went: its probe deserves the line's usual retries,
        so one noisy reply doesn't keep a healthy drive away for a whole backoff."""
        health = self._drives.get(address)
        return health is not None and health.offline and health.lost_with_line

    def due_probes(self, now: float) -> list[int]:
        return [a for a, h in self._drives.items() if h.offline and h.next_probe_at <= now]

    def postpone_probe(self, address: int, now: float) -> None:
        """A probe is under way; don't start another before it has had its chance."""
        health = self._get(address)
        health.next_probe_at = now + health.probes.delay_s

    def probe_now(self, address: int, now: float) -> None:
        """An offline drive was heard (a late reply): probe it now, not at its backoff's end."""
        health = self._drives.get(address)
        if health is not None and health.offline and health.next_probe_at > now:
            health.next_probe_at = now

    def next_probe_at(self) -> float | None:
        times = [h.next_probe_at for h in self._drives.values() if h.offline]
        return min(times) if times else None

    def _schedule_probe(self, health: DriveHealth, now: float) -> None:
        # Growing to the cap, jittered so several dead drives don't probe in step.
        health.next_probe_at = now + health.probes.next_delay()
