"""Overall progress and an estimated end for long commands (`bench`, `stress`).

On a terminal one status line at the bottom is redrawn every second ("12 of 26 cases, 46 %,
ends ~14:03 (in 5 min 10 s)"), and lines the command prints go above it. When the output is not
a terminal (a log file, CI) there is no redrawing: a plain line at each step instead.

The estimate is the planned work still to do, scaled by how long the work done so far took
against its plan (start-up of processes is part of that, and it varies from machine to machine).
"""

from __future__ import annotations

import threading
import time
from typing import TextIO

REDRAW_S = 1.0
CLEAR_LINE = "\r\033[K"


def duration_text(seconds: float) -> str:
    """'45 s', '5 min 10 s', '1 h 02 min'."""
    seconds = max(0, round(seconds))
    if seconds < 60:
        return f"{seconds} s"
    if seconds < 3600:
        return f"{seconds // 60} min {seconds % 60:02d} s"
    return f"{seconds // 3600} h {seconds % 3600 // 60:02d} min"


class Progress:
    """`planned_s` of work for `what`; `advance()` as parts finish, `step()` to name the next."""

    def __init__(self, what: str, planned_s: float, out: TextIO) -> None:
        self.what = what
        self.planned_s = planned_s
        self.out = out
        self.terminal = out.isatty()
        self.started = time.monotonic()
        self.done_s = 0.0
        """Planned seconds of the parts finished."""
        self._done_at = self.started
        self.current = ""
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._ticker: threading.Thread | None = None

    def __enter__(self) -> Progress:
        if self.terminal:
            self._ticker = threading.Thread(target=self._tick, name="progress", daemon=True)
            self._ticker.start()
        return self

    def __exit__(self, *exc_info: object) -> None:
        self._stop.set()
        if self._ticker is not None:
            self._ticker.join()
        with self._lock:
            if self.terminal:
                self.out.write(CLEAR_LINE)
                self.out.flush()

    def step(self, current: str) -> None:
        """The part now running; a plain line when not on a terminal."""
        with self._lock:
            self.current = current
            if not self.terminal:
                print(f"{self.what}: {self.status()}", file=self.out, flush=True)
            else:
                self._draw()

    def note(self, text: str) -> None:
        """A line worth keeping ("serial port: back after 0.4 s"), printed as `what: text`; when
        not on a terminal, with the overall status after it."""
        if self.terminal:
            self.print(f"{self.what}: {text}", self.out)
        else:
            with self._lock:
                print(f"{self.what}: {text} ({self.status()})", file=self.out, flush=True)

    def advance(self, planned_s: float) -> None:
        """A part of `planned_s` planned seconds is finished."""
        with self._lock:
            self.done_s = min(self.planned_s, self.done_s + planned_s)
            self._done_at = time.monotonic()

    def print(self, text: str, out: TextIO) -> None:
        """Print `text` on `out` above the status line (which is redrawn under it)."""
        with self._lock:
            if self.terminal:
                self.out.write(CLEAR_LINE)
                self.out.flush()
            print(text, file=out, flush=True)
            if self.terminal:
                self._draw()

    def total_s(self) -> float:
        """The whole run's expected length: the plan, at the pace of the parts finished so far
        (real seconds per planned second), or the plan itself before any part is finished."""
        if self.done_s <= 0:
            return self.planned_s
        return self.planned_s * (self._done_at - self.started) / self.done_s

    def fraction(self, now: float) -> float:
        total = self.total_s()
        return 1.0 if total <= 0 else min((now - self.started) / total, 0.99)

    def status(self, now: float | None = None) -> str:
        now = time.monotonic() if now is None else now
        left = max(self.started + self.total_s() - now, 0.0)
        end = time.strftime("%H:%M:%S", time.localtime(time.time() + left))
        parts = [self.current] if self.current else []
        parts += [
            f"{self.fraction(now):.0%} done",
            f"{duration_text(now - self.started)} elapsed",
            f"ends ~{end} (in {duration_text(left)})",
        ]
        return ", ".join(parts)

    def _draw(self) -> None:
        self.out.write(f"{CLEAR_LINE}{self.what}: {self.status()}")
        self.out.flush()

    def _tick(self) -> None:
        while not self._stop.wait(REDRAW_S):
            with self._lock:
                self._draw()
