"""`invt-gateway simulate --masters N` as the redundancy tests start it: one simulated RS-485
line whose drives N masters share (each on a pty of its own), its counters read through its
control commands on stdin (`stats`: collisions, and each master's frames)."""

from __future__ import annotations

import contextlib
import json
import threading
from collections.abc import Iterator
from typing import Any

from tests.support.processes import SimulatorProcess


class SharedLine(SimulatorProcess):
    """The simulator process, the masters' paths, and its control commands."""

    def __init__(self, masters: int, *arguments: str) -> None:
        super().__init__(["--masters", str(masters), *arguments], paths=masters, control=True)
        self._asking = threading.Lock()

    def command(self, text: str) -> str:
        """One control command; its one line of answer."""
        assert self.process.stdin is not None
        with self._asking:
            before = len(self.output.lines)
            self.process.stdin.write(text + "\n")
            self.process.stdin.flush()
            self.output.wait_for_count("", before + 1, 5.0)
            return self.output.lines[before]

    def stats(self) -> dict[str, Any]:
        answer = self.command("stats")
        assert answer.startswith("ok "), answer
        stats: dict[str, Any] = json.loads(answer[3:])
        return stats

    def frames_by(self, master: int) -> int:
        """Frames the `master`-th master (from 0) has transmitted so far."""
        return int(self.stats()["masters"][master]["frames"])


@contextlib.contextmanager
def shared_line(masters: int, *arguments: str) -> Iterator[SharedLine]:
    line = SharedLine(masters, *arguments)
    try:
        yield line
    finally:
        line.stop()
