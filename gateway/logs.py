"""Logging set-up: text for a terminal, one JSON object per line for journald or Loki."""

from __future__ import annotations

import json
import logging
import sys
import time

FRAMES = logging.getLogger("gateway.frames")
"""Hex dumps of every RTU frame, at debug level: `logging: {level: debug}` shows what went on
the wire, byte for byte, without a line analyser."""

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


def setup_logging(level: str = "info", fmt: str = "text") -> None:
    handler = logging.StreamHandler(sys.stderr)
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
