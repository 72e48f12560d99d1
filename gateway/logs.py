"""Logging set-up: text for a terminal, one JSON object per line for journald or Loki."""

from __future__ import annotations

import json
import logging
import sys
import time
from collections.abc import Callable

FRAMES = logging.getLogger("gateway.frames")
"""Hex dumps of every RTU frame, at debug level: `logging: {level: debug}` shows what went on
the wire, byte for byte, without a line analyser."""
# logging's own cache, a private dict: a Python without it gives an empty one here, so every
# check falls through to `isEnabledFor` (right, only slower) rather than failing at import.
FRAMES_CACHED: Callable[[int], bool | None] = vars(FRAMES).get("_cache", {}).get
"""What `FRAMES.isEnabledFor` has remembered for a level: True, False, or None when not known
(since any logger's level or `logging.disable` last changed: logging clears this same dict
then). `FRAMES_CACHED(logging.DEBUG) is not False and FRAMES.isEnabledFor(logging.DEBUG)` is
`isEnabledFor`'s answer, with no Python call in the usual case (dumps off): once per
transaction, that call is some 800 instructions (callgrind)."""

_LEVELS = {
    "debug": logging.DEBUG,
    "info": logging.INFO,
    "warning": logging.WARNING,
    "error": logging.ERROR,
}


class JsonFormatter(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        entry = {
            "time": time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(record.created))
            + f".{int(record.msecs):03d}Z",
            "level": record.levelname.lower(),
            "logger": record.name,
            "message": record.getMessage(),
        }
        if record.exc_info:
            entry["exception"] = self.formatException(record.exc_info)
        return json.dumps(entry, ensure_ascii=False)


REPEAT_WINDOW_S = 60.0


def repeated(source: str) -> dict[str, str]:
    """`extra=` for a log call that a hostile client can repeat at will (a malformed frame, a
    refused connection): the first is logged at once, the rest once a minute with their count."""
    return {"repeat_source": source}


class RepeatFilter(logging.Filter):
    """Aggregates records marked with `repeated(source)`: one line per source per minute.

    The first record of a source passes. Further ones within `REPEAT_WINDOW_S` are held back and
    counted; the first after the window passes with "(N more like this since HH:MM:SS)" added,
    and starts a new window. The counters in the metrics see every one: only the log is spared.
    """

    def __init__(self, window_s: float = REPEAT_WINDOW_S) -> None:
        super().__init__()
        self.window_s = window_s
        self._windows: dict[str, tuple[float, int]] = {}  # source -> (window start, held back)

    def filter(self, record: logging.LogRecord) -> bool:
        source = getattr(record, "repeat_source", None)
        if source is None:
            return True
        started, held = self._windows.get(source, (0.0, 0))
        now = record.created
        if now - started < self.window_s:
            self._windows[source] = (started, held + 1)
            return False
        self._windows[source] = (now, 0)
        if held:
            since = time.strftime("%H:%M:%S", time.localtime(started))
            record.msg = f"{record.msg} ({held} more like this since {since})"
        return True

    def held_back(self) -> dict[str, int]:
        """Records held back so far in each source's current window."""
        return {source: held for source, (_, held) in self._windows.items() if held}


def setup_logging(level: str = "info", fmt: str = "text") -> None:
    handler = logging.StreamHandler(sys.stderr)
    handler.addFilter(RepeatFilter())
    if fmt == "json":
        handler.setFormatter(JsonFormatter())
    else:
        handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)-7s %(name)s: %(message)s"))
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(_LEVELS.get(level, logging.INFO))


def frame_dump_enabled() -> bool:
    """True at debug level: lets a caller skip building a frame it would only dump."""
    return FRAMES.isEnabledFor(logging.DEBUG)


def dump_frame(bus: str, direction: str, frame: bytes) -> None:
    """Log one frame as hex ("line1 tx 01 03 21 00 00 01 8e 36"); costs one check when off."""
    if FRAMES.isEnabledFor(logging.DEBUG):
        FRAMES.debug("%s %s %s", bus, direction, frame.hex(" ") if frame else "(nothing)")
