"""The box's fitness told to Keepalived at once, in a file it watches (`redundancy.fault_file`,
Keepalived's `track_file` with `weight 0`): `0` while this box can be the line's master, `1`
while it can't (no port open on any line for `PORTLESS_S`: its adapter unplugged; the gateway
stopping). Keepalived reads the file as soon as it is replaced (inotify): on `1` the instance
goes FAULT at once and, if it was MASTER, sends an advert of priority 0, on which the other box
becomes MASTER after its skew time (a fraction of `advert_int`) instead of waiting for three
adverts missed. The track script (`invt-gateway-notify.sh check`, every second) stays the way
a dead or stuck gateway, which writes nothing more, is noticed.

The file is replaced whole (a new file renamed over it: Keepalived sees IN_MOVED_TO and reads
the value, never half of it), so it may live in a directory only the gateway can write (its
store's, /var/lib/invt-gateway under systemd, which outlives a restart: Keepalived watches the
directory, and one that vanished would be watched no more)."""

from __future__ import annotations

import logging
import os
from pathlib import Path

log = logging.getLogger(__name__)


class FaultFile:
    """Writes `0` or `1` to `path` when the box's fitness changes (and at start)."""

    def __init__(self, path: str) -> None:
        self.path = Path(path)
        self._told: bool | None = None
        """The last value written: True for fit (0); None: nothing yet."""
        self._failed = False

    def tell(self, fit: bool, why: str = "") -> None:
        if fit is self._told:
            return
        temporary = self.path.with_name(f".{self.path.name}.{os.getpid()}.tmp")
        try:
            temporary.write_text("0\n" if fit else "1\n")
            os.replace(temporary, self.path)
        except OSError as exc:
            # Keepalived's track script still finds an unfit box, a second or two later.
            level = logging.DEBUG if self._failed else logging.ERROR
            log.log(level, "redundancy: can't write the fault file %s: %s", self.path, exc)
            self._failed = True
            return
        self._told, self._failed = fit, False
        if fit:
            log.info("redundancy: %s says 0: this box can be the line's master", self.path)
        else:
            log.warning("redundancy: %s says 1: %s", self.path, why or "unfit")
