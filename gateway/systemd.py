"""Talking to systemd as a `Type=notify` service: READY=1, WATCHDOG=1, STOPPING=1, STATUS=...

The protocol is one datagram of `KEY=value` lines to the unix socket named in `NOTIFY_SOCKET`
(a path, or an abstract name written with a leading "@"). Outside systemd the variable is unset
and every call does nothing, so the service runs the same from a terminal or in Docker.

The watchdog is pinged from the event loop itself, not from a thread: a loop that is stuck (a
blocking call, a busy coroutine) stops pinging, and systemd restarts the service, which is the
point of `WatchdogSec=`.
"""

from __future__ import annotations

import asyncio
import logging
import os
import socket
from collections.abc import Mapping

log = logging.getLogger(__name__)

NOTIFY_SOCKET = "NOTIFY_SOCKET"
WATCHDOG_USEC = "WATCHDOG_USEC"
WATCHDOG_PID = "WATCHDOG_PID"


class Notifier:
    """Sends state changes to the service manager; a no-op when there is none."""

    def __init__(self, address: str | None) -> None:
        self.address = address
        self._socket: socket.socket | None = None

    @classmethod
    def from_environment(cls, environ: Mapping[str, str] = os.environ) -> Notifier:
        return cls(environ.get(NOTIFY_SOCKET) or None)

    @property
    def enabled(self) -> bool:
        return self.address is not None

    def notify(self, *fields: str) -> bool:
        """Send `fields` ("READY=1", "STATUS=...") as one message; False if it could not go."""
        if self.address is None:
            return False
        target = "\0" + self.address[1:] if self.address.startswith("@") else self.address
        try:
            if self._socket is None:
                self._socket = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
            self._socket.sendto("\n".join(fields).encode(), target)
        except OSError as exc:
            # The service must keep working when the manager's socket is gone; say it once.
            log.warning("cannot notify the service manager at %s: %s", self.address, exc)
            self.close()
            self.address = None
            return False
        return True

    def ready(self, status: str) -> bool:
        return self.notify("READY=1", f"STATUS={status}", f"MAINPID={os.getpid()}")

    def stopping(self, status: str = "stopping") -> bool:
        return self.notify("STOPPING=1", f"STATUS={status}")

    def watchdog(self) -> bool:
        return self.notify("WATCHDOG=1")

    def close(self) -> None:
        if self._socket is not None:
            self._socket.close()
            self._socket = None


def watchdog_interval_s(environ: Mapping[str, str] = os.environ) -> float | None:
    """The interval systemd expects a ping within (`WatchdogSec=`), or None when it expects none.

    `WATCHDOG_PID`, when set, names the process meant: a child that inherited the variables
    must not ping on its parent's behalf.
    """
    usec = environ.get(WATCHDOG_USEC, "")
    pid = environ.get(WATCHDOG_PID, "")
    if not usec.isdigit() or int(usec) == 0:
        return None
    if pid and pid != str(os.getpid()):
        return None
    return int(usec) / 1_000_000


async def keep_watchdog(notifier: Notifier, interval_s: float) -> None:
    """Ping at half the interval, as sd_watchdog_enabled(3) advises, until cancelled."""
    while True:
        notifier.watchdog()
        await asyncio.sleep(interval_s / 2)
