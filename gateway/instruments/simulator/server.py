"""`LineServer`: one thread serving one or several simulated lines.

Each line keeps its own port, drives, clock of frames and gaps; the thread only waits for
whichever of them has something to do: bytes from its master, a reply due, the silence that
ends a request. Many lines in one thread cost one wake-up per event, not one thread (and one
spinning wait) per line, so a bench of 32 lines leaves the cores to the gateway it measures.
"""

from __future__ import annotations

import logging
import select
import sys
import threading
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING, Final

from gateway.timer_slack import tighten_timer_slack

if TYPE_CHECKING:
    from gateway.instruments.simulator.line import SimulatedLine

log = logging.getLogger(__name__)

STOP_TIMEOUT_S: Final = 1.0
GIL_SWITCH_INTERVAL_S: Final = 0.0002


class LineServer:
    """Serves `lines` from one thread, from `start()` to `stop()`."""

    def __init__(self, lines: Sequence[SimulatedLine]) -> None:
        if not lines:
            raise ValueError("a line server needs at least one line")
        self.lines = tuple(lines)
        self._thread: threading.Thread | None = None
        self._stopping = False

    def start(self) -> None:
        """Open every line's port, then serve them all."""
        if self._thread is not None:
            raise RuntimeError("the line server is already started")
        opened: list[SimulatedLine] = []
        try:
            for line in self.lines:
                line._open(self)
                opened.append(line)
        except BaseException:
            for line in opened:
                line._close()
            raise
        # The simulated drives may share a process with an event loop (the demo, the tests):
        # with Python's default 5 ms switch interval a busy loop would hold the GIL, and the
        # drives' answers, that long.
        sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
        self._stopping = False
        name = "simulated-line" if len(self.lines) == 1 else "simulated-lines"
        self._thread = threading.Thread(target=self._serve, name=name, daemon=True)
        for line in self.lines:
            line._thread = self._thread
        self._thread.start()

    def stop(self) -> None:
        """Stop serving (promptly), close every line's port. Safe to call twice."""
        thread = self._thread
        if thread is None:
            return
        self._stopping = True
        for line in self.lines:
            line._stopping = True
            line._wake()
        thread.join(STOP_TIMEOUT_S)
        if thread.is_alive():
            log.error("simulated line thread did not stop within %.1f s", STOP_TIMEOUT_S)
        self._thread = None
        for line in self.lines:
            line._close()

    def _serve(self) -> None:
        tighten_timer_slack()  # a drive answers on time, not when the kernel batches wake-ups
        while not self._stopping:
            try:
                self._serve_once()
            except Exception:  # the lines must outlive a bug in one exchange; the log shows it
                log.exception("simulated line: error while serving")

    def _serve_once(self) -> None:
        watched: list[int] = []
        deadlines: list[float | None] = []
        for line in self.lines:
            watched += line._watched()
            deadlines.append(line._deadline())
        due = [deadline for deadline in deadlines if deadline is not None]
        timeout = max(0.0, min(due) - time.monotonic()) if due else None
        readable, _, _ = select.select(watched, [], [], timeout)
        ready = set(readable)
        now = time.monotonic()
        for line, deadline in zip(self.lines, deadlines, strict=True):
            # A line with nothing to read and nothing due has nothing to do this pass.
            if (deadline is not None and deadline <= now) or any(
                fd in ready for fd in line._watched()
            ):
                line._serve_ready(ready)
