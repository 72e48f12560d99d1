"""`LineServer`: one thread serving one or several simulated lines.

Each line keeps its own port, drives, clock of frames and gaps; the thread only waits for
whichever of them has something to do: bytes from its master, a reply due, the silence that
ends a request. Many lines in one thread cost one wake-up per event, not one thread (and one
spinning wait) per line, so a bench of 32 lines leaves the cores to the gateway it measures.
"""

from __future__ import annotations

import contextlib
import logging
import math
import selectors
import sys
import threading
import time
from collections.abc import Container, Sequence
from typing import Final, Protocol

from gateway.timer_slack import tighten_timer_slack
from gateway.timerfd import DeadlineTimer

log = logging.getLogger(__name__)

STOP_TIMEOUT_S: Final = 1.0
_NOT_YET: Final = object()
"""A line's port before the serving thread first looks at it (its port may be None)."""
GIL_SWITCH_INTERVAL_S: Final = 0.0002
_TIMER: Final = -1
"""The selector's data for the deadline's timerfd (a line's is its index)."""


class ServedLine(Protocol):
    """What the server asks of each line it serves, and all it knows of one (`SimulatedLine`
    is one); every call but `open_for` and `close_port` comes from the serving thread."""

    def open_for(self, server: LineServer) -> None:
        """Before the thread serves the line: its port and its wake-up descriptor."""

    def served_from(self, thread: threading.Thread) -> None:
        """The thread that serves the line from now on."""

    def stop_serving(self) -> None:
        """The thread stops: end the pass under way at once, and wake the thread."""

    def close_port(self) -> None:
        """After the thread stopped: the port and the wake-up descriptor closed."""

    @property
    def endpoint(self) -> object | None:
        """The port the thread reads: another object after a replug (watch it again)."""

    def watched(self) -> list[int]:
        """The descriptors to wait on for this line."""

    def deadline(self) -> float | None:
        """When to serve the line next with nothing to read (monotonic); None: not before."""

    def serve_ready(self, readable: Container[int], woke_at: float) -> None:
        """One pass for the line: `readable` are the descriptors found ready at `woke_at`."""


class LineServer:
    """Serves `lines` from one thread, from `start()` to `stop()`."""

    def __init__(self, lines: Sequence[ServedLine]) -> None:
        if not lines:
            raise ValueError("a line server needs at least one line")
        self.lines = tuple(lines)
        self._thread: threading.Thread | None = None
        self._stopping = False
        # The serving thread's own (see `_serve`).
        self._watched: list[tuple[int, ...]] = []
        self._endpoints: list[object] = []
        self._deadlines: list[float] = []
        self._timer: DeadlineTimer
        """The soonest deadline's wake-up (see `_open_selector`): the serving thread's."""
        self._timer_at = math.inf
        """The deadline `_timer` is armed at; inf when disarmed."""

    def start(self) -> None:
        """Open every line's port, then serve them all."""
        if self._thread is not None:
            raise RuntimeError("the line server is already started")
        opened: list[ServedLine] = []
        try:
            for line in self.lines:
                line.open_for(self)
                opened.append(line)
        except BaseException:
            for line in opened:
                line.close_port()
            raise
        # The simulated drives may share a process with an event loop (the demo, the tests):
        # with Python's default 5 ms switch interval a busy loop would hold the GIL, and the
        # drives' answers, that long.
        sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
        self._stopping = False
        name = "simulated-line" if len(self.lines) == 1 else "simulated-lines"
        self._thread = threading.Thread(target=self._serve, name=name, daemon=True)
        for line in self.lines:
            line.served_from(self._thread)
        self._thread.start()

    def stop(self) -> None:
        """Stop serving (promptly), close every line's port. Safe to call twice."""
        thread = self._thread
        if thread is None:
            return
        self._stopping = True
        for line in self.lines:
            line.stop_serving()
        thread.join(STOP_TIMEOUT_S)
        if thread.is_alive():
            log.error("simulated line thread did not stop within %.1f s", STOP_TIMEOUT_S)
        self._thread = None
        for line in self.lines:
            line.close_port()

    def _serve(self) -> None:
        selector = self._open_selector()
        tighten_timer_slack()  # a drive answers on time, not when the kernel batches wake-ups
        # What the thread waits on, by line: its descriptors (in the selector, the line's
        # index as data), its port (a new one after a replug, maybe under a reused number) and
        # its deadline (inf: none). A line's change only while it is served (control calls
        # run then too), so each pass looks again at the lines it served, not at every line.
        self._watched = [() for _ in self.lines]
        self._endpoints = [_NOT_YET for _ in self.lines]
        self._deadlines = [math.inf for _ in self.lines]
        try:
            for index in range(len(self.lines)):
                self._look_again(selector, index)
            while not self._stopping:
                try:
                    self._serve_once(selector)
                except Exception:  # the lines must outlive a bug in one exchange; the log shows it
                    log.exception("simulated line: error while serving")
        finally:
            selector.close()
            self._timer.close()

    def _open_selector(self) -> selectors.BaseSelector:
        """epoll with the deadline on a timerfd: a wait costs the same however many lines are
        served, and ends on the microsecond. Where there is no timerfd, select(2): its timeout
        is to the microsecond too (epoll's and poll's are whole milliseconds, and a reply due
        in the middle of one would go out up to a millisecond late), but every wait scans every
        line's descriptors (at 32 lines, most of the thread's time went there)."""
        self._timer, self._timer_at = DeadlineTimer(), math.inf
        if self._timer.fd < 0:
            return selectors.SelectSelector()
        selector = selectors.EpollSelector()
        selector.register(self._timer.fd, selectors.EVENT_READ, _TIMER)
        return selector

    def _serve_once(self, selector: selectors.BaseSelector) -> None:
        soonest = min(self._deadlines)
        timeout = None if soonest == math.inf else max(0.0, soonest - time.monotonic())
        timer = self._timer
        # The timerfd ends the wait (armed anew only when the soonest deadline moved: arming
        # clears the expiry of the one before); the selector waits without a timeout. Where
        # arming is refused (never, in practice), the selector's own timeout serves.
        if timer.fd >= 0 and timeout != 0.0 and (soonest == self._timer_at or self._arm(soonest)):
            timeout = None
        events = selector.select(timeout)
        now = time.monotonic()
        ready = {key.fd for key, _ in events}
        # A line with nothing to read and nothing due has nothing to do this pass.
        serving = {index for index, deadline in enumerate(self._deadlines) if deadline <= now}
        serving.update(key.data for key, _ in events if key.data != _TIMER)
        # The soonest due first: a line waiting out its reply's last microseconds on the clock
        # holds up the others, which are due after it so.
        for index in sorted(serving, key=self._deadlines.__getitem__):
            self.lines[index].serve_ready(ready, now)
            self._look_again(selector, index)

    def _arm(self, soonest: float) -> bool:
        """The timerfd at `soonest` (disarmed for inf: no line has anything due)."""
        timer = self._timer
        if not (timer.disarm() if soonest == math.inf else timer.arm_at(soonest)):
            return False
        self._timer_at = soonest
        return True

    def _look_again(self, selector: selectors.BaseSelector, index: int) -> None:
        """After serving the line at `index`: what to wait on for it next."""
        line = self.lines[index]
        endpoint = line.endpoint
        if endpoint is not self._endpoints[index]:
            for fd in self._watched[index]:
                with contextlib.suppress(KeyError):
                    selector.unregister(fd)
            self._watched[index] = tuple(line.watched())
            for fd in self._watched[index]:
                selector.register(fd, selectors.EVENT_READ, index)
            self._endpoints[index] = endpoint
        deadline = line.deadline()
        self._deadlines[index] = math.inf if deadline is None else deadline
