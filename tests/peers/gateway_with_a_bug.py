"""`invt-gateway run --config FILE`, whose poller is made to die of a bug once it is ready.

A real feature and a real bug, no mock: once a drive's poll is answered, the drive loses its poll
timers (state the poll loop relies on, made inconsistent as a bug elsewhere could make it), and
the loop fails (`min()` of nothing) outside the guard that keeps one failed poll from ending the
polling.
Everything else is what `invt-gateway run` does: `python -m tests.peers.gateway_with_a_bug FILE`.
"""

from __future__ import annotations

import asyncio
import sys

from gateway.app import Application
from gateway.commands.run import load_or_report, serve
from gateway.logs import setup_logging
from gateway.poller import DriveEvent
from gateway.profile.telemetry import Telemetry


class TimerThief:
    """A poll listener that, told of a drive's first answered poll, takes its poll timers."""

    def __init__(self, app: Application) -> None:
        self.app = app

    def state_updated(self, drive: str, telemetry: Telemetry) -> None:
        self.app.poller.drives[drive].timers.clear()

    def availability_changed(self, drive: str, online: bool) -> None:
        pass

    def drive_event(self, event: DriveEvent) -> None:
        pass


def break_the_poller(app: Application) -> None:
    app.poller.add_listener(TimerThief(app))


def main(path: str) -> int:
    config = load_or_report(path)
    if config is None:
        return 2
    setup_logging(config.logging.level, config.logging.format)
    return asyncio.run(serve(config, on_ready=break_the_poller))


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
