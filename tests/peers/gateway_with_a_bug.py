"""`invt-gateway run --config FILE`, one of whose features is made to die of a bug once it is
ready: `python -m tests.peers.gateway_with_a_bug FILE [poller|console-sampler]`.

Real features and real bugs, no mock: state a feature relies on is made inconsistent, as a bug
elsewhere could make it.
- poller (the default): once a drive's poll is answered, the drive loses its poll timers, and
  the loop fails (`min()` of nothing) outside the guard that keeps one failed poll from ending
  the polling.
- console-sampler: a bus appears in the application's map of buses that the console's live
  state was never told of, and the sampler, sampling every bus, fails on it (`KeyError`).
Everything else is what `invt-gateway run` does.
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


def break_the_console_sampler(app: Application) -> None:
    app.buses["unannounced"] = next(iter(app.buses.values()))


BUGS = {"poller": break_the_poller, "console-sampler": break_the_console_sampler}


def main(path: str, bug: str = "poller") -> int:
    config = load_or_report(path)
    if config is None:
        return 2
    setup_logging(config.logging.level, config.logging.format)
    return asyncio.run(serve(config, on_ready=BUGS[bug]))


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:]))
