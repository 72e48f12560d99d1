"""A standby's port on one line, opened only to listen: when the line was last heard, and the
frames heard on it. It never writes: no frame, no byte (the port is the bus's own kind,
`gateway.bus.port.open_port`, with its RS-485 driver set to receive, and nothing here calls a
write). The bus opens the port again itself once this gateway takes the line.

A port that can't be opened (the adapter unplugged) is tried again every `REOPEN_S`, said once
in the log; such a line is heard by nobody, so its silence proves nothing: `silent_for` is 0
until it is open. A takeover goes by the lines that are heard (with none heard it waits): a line
whose adapter is missing can't be served by this box either, and its bus, once the adapter is
back, is watched for another master from its first byte.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Callable
from typing import Final

from gateway.bus.line_settings import LineSettings
from gateway.bus.port import Port, open_port
from gateway.bus.receiver import Receiver
from gateway.errors import PortError
from gateway.redundancy.frames import Frame, FrameCutter, Kind

log = logging.getLogger(__name__)

REOPEN_S: Final = 0.5
"""A port that can't be opened (or failed) is tried again this often: well within
`PORTLESS_S`, so one glitch doesn't make the box unfit."""


class LineEar:
    """What one line's bytes say, as they are heard: when last, and the frames among them
    (cut with `FrameCutter`, a silence of t3.5 ending each)."""

    def __init__(self, settings: LineSettings, told: Callable[[Frame], None] | None = None) -> None:
        self.settings = settings
        self._told = told
        self._cutter = FrameCutter()
        self.heard_at = 0.0
        """When the last byte was heard (`time.monotonic()`); 0.0: nothing yet."""
        self.requests = 0
        """Requests heard (a master's)."""
        self.replies = 0
        self._silence: asyncio.TimerHandle | None = None

    def heard(self, data: bytes) -> None:
        now = time.monotonic()
        if self.heard_at and now - self.heard_at > self.settings.gap_s:
            self._frames(self._cutter.silence())
        self.heard_at = now
        self._frames(self._cutter.feed(data))
        # The frame held last is decided when the line has been quiet for t3.5.
        if self._silence is not None:
            self._silence.cancel()
        loop = asyncio.get_running_loop()
        self._silence = loop.call_later(self.settings.gap_s, self._went_quiet)

    def _went_quiet(self) -> None:
        self._silence = None
        self._frames(self._cutter.silence())

    def _frames(self, frames: list[Frame]) -> None:
        for frame in frames:
            if frame.kind is Kind.REPLY:
                self.replies += 1
            else:
                self.requests += 1
            if self._told is not None:
                self._told(frame)

    def close(self) -> None:
        if self._silence is not None:
            self._silence.cancel()
            self._silence = None


class LineListener:
    """One line's port, open to listen while this gateway is not the active one."""

    def __init__(
        self,
        settings: LineSettings,
        lost: Callable[[], None] | None = None,
        told: Callable[[Frame], None] | None = None,
    ) -> None:
        """`told`: each frame heard (another master's requests, for the role machine)."""
        self.settings = settings
        self._lost = lost
        """Told when the open port fails (the role machine counts the time without a port)."""
        self.ear = LineEar(settings, told)
        self.opened_at = 0.0
        """When the port was opened (0.0: not open): the line is heard from then."""
        self._port: Port | None = None
        self._task: asyncio.Task[None] | None = None
        self._failures = 0

    @property
    def open(self) -> bool:
        return self._port is not None and self._port.usable

    def silent_for(self, now: float) -> float:
        """How long the line has been heard silent: 0 while the port is not open."""
        if not self.open:
            return 0.0
        return now - max(self.opened_at, self.ear.heard_at)

    def start(self) -> None:
        """Open the port, now or as soon as it can be (in the background)."""
        if self._task is None:
            self._task = asyncio.get_running_loop().create_task(
                self._keep_open(), name=f"listen:{self.settings.name}"
            )

    async def stop(self) -> None:
        """Close the port (the bus is about to open it, or the gateway stops)."""
        task, self._task = self._task, None
        if task is not None:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
        self._close()

    async def _keep_open(self) -> None:
        try:
            while True:
                if not self.open:
                    self._close()
                    self._try_open()
                await asyncio.sleep(REOPEN_S)
        finally:
            self._close()

    def _try_open(self) -> None:
        try:
            self._port = open_port(
                self.settings, Receiver(self.settings), self.ear.heard, self._failed
            )
        except PortError as exc:
            self._failures += 1
            level = logging.WARNING if self._failures == 1 else logging.DEBUG
            log.log(level, "redundancy: %s: can't listen to the line: %s", self.where, exc)
            return
        self.opened_at = time.monotonic()
        self._failures = 0
        log.info("redundancy: %s: listening to the line (never transmitting)", self.where)

    def _close(self) -> None:
        port, self._port = self._port, None
        self.opened_at = 0.0
        self.ear.close()
        if port is not None:
            port.close()

    @property
    def where(self) -> str:
        return self.settings.where

    def _failed(self) -> None:
        """The port failed between reads (`open` turns False): opened again by `_keep_open`."""
        if self._lost is not None:
            self._lost()
