"""The primary host application's STATE (specification 3.0, "Primary Host Application").

The host publishes `spBv1.0/STATE/<host_id>` retained, QoS 1, as JSON: `{"online": true,
"timestamp": <ms>}` when it connects, and its will `{"online": false, ...}` for when it dies.
An edge node that names a primary host publishes only while that host is online; a STATE older
than the newest one seen (its timestamp) is stale and ignored, whatever it says.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass

log = logging.getLogger(__name__)


@dataclass(slots=True)
class PrimaryHost:
    host_id: str
    online: bool = False
    """Until its STATE says otherwise, the host is taken as offline: nothing is published."""
    timestamp: int = -1

    def update(self, payload: bytes) -> bool:
        """Take a STATE message; True when it changed whether the host is online."""
        try:
            state = json.loads(payload)
            online, timestamp = state["online"], state["timestamp"]
        except (ValueError, TypeError, KeyError):
            log.warning("Sparkplug: a STATE of %s that is not Sparkplug 3.0's JSON", self.host_id)
            return False
        if not isinstance(online, bool) or not isinstance(timestamp, int):
            log.warning("Sparkplug: a STATE of %s without online/timestamp", self.host_id)
            return False
        if timestamp < self.timestamp:
            log.info("Sparkplug: an older STATE of %s ignored", self.host_id)
            return False
        self.timestamp = timestamp
        changed = online != self.online
        self.online = online
        if changed:
            log.warning(
                "Sparkplug: primary host %s is %s", self.host_id, "online" if online else "offline"
            )
        return changed
