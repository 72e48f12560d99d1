"""SIGTERM ends an instrument (`bench`, `stress`) as Ctrl-C does: by an exception.

`timeout`, a CI runner and `kill` send SIGTERM, whose default ends the process at once: the
`with` blocks that stop the gateway, the simulated drives and the broker it started never ran,
and they were left running. An orphaned gateway went on reopening its port, a pty whose number
the kernel hands to the next run's simulated line, whose drives then seemed offline (0BH) to
that run's own gateway. Raised as SystemExit instead, the exception unwinds through those blocks
(asyncio.run cancels the run's tasks, which runs theirs) and every child is stopped.
"""

from __future__ import annotations

import signal
from types import FrameType


def stop_on_terminate() -> None:
    """From now on, SIGTERM raises SystemExit (exit status 128 + 15) in the main thread."""

    def terminate(number: int, _frame: FrameType | None) -> None:
        raise SystemExit(128 + number)

    signal.signal(signal.SIGTERM, terminate)
