"""The two boxes' configurations compared while both run: "a reload on one tells the other's
operator" (issue 48).

Each box tells the other what it runs, as digests of what both must share (`gateway.config.
peer`: the split `check-config --peer` uses, one key each, no value and no secret), retained on
MQTT (`gateway.mqtt.role`), and compares the other's with its own (`PeerConfig`): at its start,
at every announcement of the other's (the other's reload, or its restart with a new file) and
after its own reload. When they differ it says so once, with the keys and not their values: a
WARNING in the log, a `peer_config_differs` event (and `peer_config_alike` once alike again),
`peer_config` in `role status`, /health and the console's banner, and a metric.

What is compared is what each box runs: an active box's file once reloaded, a standby's as it
started (it applies a file at its restart only). A file reloaded on both boxes differs until
the standby restarts: the box that takes over would run the old one.
"""

from __future__ import annotations

import logging
import re
import time
from collections.abc import Callable, Mapping
from typing import Any, Final

from gateway.poller.drive_state import iso_time
from gateway.store import EventStore, EventType

log = logging.getLogger(__name__)

SHOWN_KEYS: Final = 20
"""Keys named in the log line, the event and the status (their count says how many in all)."""


class PeerConfig:
    """This box's running configuration against the other box's, as it announced it."""

    def __init__(
        self,
        running: Callable[[], Mapping[str, str]],
        events: EventStore | None = None,
    ) -> None:
        self._running = running
        self._events = events
        self._peer: str | None = None
        self._theirs: dict[str, str] | None = None
        self.differs: list[str] = []
        """The shared keys whose values differ (none while alike, or not heard yet)."""
        self.since: float | None = None
        """Since when they differ (or agree), wall-clock; None: the peer not heard yet."""

    def digests(self) -> Mapping[str, str]:
        """This box's: each shared key's digest, of the configuration it runs now."""
        return self._running()

    def heard(self, peer: str, digests: Mapping[str, str]) -> None:
        """The other box (`peer`, its box name) announced what it runs."""
        self._peer, self._theirs = peer, dict(digests)
        self._compare()

    def reloaded(self) -> None:
        """This box runs another configuration: compared again with the peer's last word."""
        if self._theirs is not None:
            self._compare()

    def status(self) -> dict[str, Any] | None:
        """For `role status`, /health and the console; None until the peer is heard."""
        if self.since is None:
            return None
        return {
            "peer": self._peer,
            "differs": self.differs[:SHOWN_KEYS],
            "count": len(self.differs),
            "since": iso_time(self.since),
        }

    def _compare(self) -> None:
        assert self._theirs is not None
        differs = differing(self.digests(), self._theirs)
        first = self.since is None
        if not first and differs == self.differs:
            return
        if first or bool(differs) != bool(self.differs):
            self.since = time.time()
        self.differs = differs
        shown = ", ".join(differs[:SHOWN_KEYS])
        more = f" and {len(differs) - SHOWN_KEYS} more" if len(differs) > SHOWN_KEYS else ""
        if differs:
            log.warning(
                "redundancy: the configuration box %s runs differs from this box's in what both "
                "must share: %s%s (`check-config --peer` says how; a standby applies its file "
                "at its restart)",
                self._peer,
                shown,
                more,
            )
            self._record(EventType.PEER_CONFIG_DIFFERS, keys=differs[:SHOWN_KEYS])
        elif not first:
            log.warning("redundancy: box %s runs this box's configuration again", self._peer)
            self._record(EventType.PEER_CONFIG_ALIKE)
        else:
            log.info("redundancy: box %s runs this box's configuration", self._peer)

    def _record(self, kind: EventType, **more: Any) -> None:
        if self._events is not None:
            data = {"peer": self._peer, "count": len(self.differs), **more}
            self._events.record(kind, data)


def differing(here: Mapping[str, str], there: Mapping[str, str]) -> list[str]:
    """The shared keys whose digests differ (or that one side has and the other doesn't), in
    key order; a named item that only one side has at all is one key (`drives[fan]`), not
    each of its keys."""
    keys: set[str] = set()
    for key in here.keys() | there.keys():
        if here.get(key) == there.get(key):
            continue
        keys.add(_item_missing(key, there if key in here else here) or key)
    return sorted(keys)


def _item_missing(key: str, other: Mapping[str, str]) -> str | None:
    """The first named item on `key`'s path (`drives[fan]`) of which `other` has no key."""
    for match in re.finditer(r"\[[^]]+\]", key):
        item = key[: match.end()]
        if not any(k == item or k.startswith((f"{item}.", f"{item}[")) for k in other):
            return item
    return None
