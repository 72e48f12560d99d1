"""The log's recent lines, kept for the console's diagnostics page.

A logging handler on the root logger while the console runs: the last `MAX_LINES` records that
passed the configured level, bounded, formatted once as they come (a line a second costs
nothing worth measuring). The page asks with a level: warnings and errors only, or everything.
"""

from __future__ import annotations

import logging
from collections import deque
from typing import Final, TypedDict

from gateway.poller.drive_state import iso_time

MAX_LINES: Final = 500
LEVELS: Final = {
    "debug": logging.DEBUG,
    "info": logging.INFO,
    "warning": logging.WARNING,
    "error": logging.ERROR,
}


class LogLine(TypedDict):
    time: str
    level: str
    logger: str
    message: str


class LogTail(logging.Handler):
    def __init__(self, max_lines: int = MAX_LINES) -> None:
        super().__init__(logging.DEBUG)
        self._lines: deque[tuple[int, LogLine]] = deque(maxlen=max_lines)

    def emit(self, record: logging.LogRecord) -> None:
        try:
            message = record.getMessage()
        except Exception:  # a bad format string must not cost the gateway its log
            message = str(record.msg)
        line = LogLine(
            time=iso_time(record.created),
            level=record.levelname.lower(),
            logger=record.name,
            message=message,
        )
        self._lines.append((record.levelno, line))

    def lines(self, level: str = "info", limit: int = MAX_LINES) -> list[LogLine]:
        """The newest `limit` lines at `level` or above, oldest first. ValueError for an
        unknown level."""
        if level not in LEVELS:
            raise ValueError(f"level must be one of {', '.join(LEVELS)}")
        floor = LEVELS[level]
        chosen = [line for levelno, line in self._lines if levelno >= floor]
        return chosen[-limit:] if limit > 0 else []

    def attach(self) -> None:
        logging.getLogger().addHandler(self)

    def detach(self) -> None:
        logging.getLogger().removeHandler(self)
