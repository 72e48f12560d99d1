"""Real `invt-gateway` subprocesses for the operations and field-tool tests.

The console script is the one installed next to the interpreter running the tests, so these tests
exercise the entry point a service manager starts, not a function call.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import yaml

from gateway.instruments.die_with_parent import die_with_parent
from tests.support import pty_cable

START_TIMEOUT_S = 15.0


ROOT = Path(__file__).resolve().parents[2]
"""The checkout: where `python -m tests.peers...` finds the peers."""


def entry_point() -> str:
    """The `invt-gateway` script of this interpreter's environment."""
    beside = Path(sys.executable).with_name("invt-gateway")
    if beside.exists():
        return str(beside)
    found = shutil.which("invt-gateway")
    assert found is not None, "invt-gateway is not installed: pip install -e ."
    return found


def run_cli(
    *args: str,
    timeout_s: float = 30.0,
    env: Mapping[str, str] | None = None,
    input_text: str | None = None,
) -> subprocess.CompletedProcess[str]:
    """Run `invt-gateway ARGS` to completion (`input_text` on its stdin); its output as text."""
    return subprocess.run(
        [entry_point(), *args],
        capture_output=True,
        text=True,
        input=input_text,
        timeout=timeout_s,
        env=None if env is None else {**os.environ, **env},
        check=False,
    )


def check_config(folder: Path, text: str) -> subprocess.CompletedProcess[str]:
    """`check-config` run on `text`, written as `config.yaml` in `folder`."""
    path = folder / "config.yaml"
    path.write_text(text)
    return subprocess.run(
        [sys.executable, "-m", "gateway", "check-config", "--config", str(path)],
        capture_output=True,
        text=True,
        timeout=60,
    )


@contextlib.contextmanager
def pymodbus_peer(module: str, *args: str) -> Iterator[str]:
    """pymodbus's RTU server as `tests.peers.<module>` plays it (`args` after its device path),
    at the far end of a pty cable; yields the device path the gateway opens."""
    with pty_cable() as (gateway_end, peer_end):
        process = subprocess.Popen(
            [sys.executable, "-m", f"tests.peers.{module}", peer_end, *args],
            cwd=ROOT,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,  # pymodbus warns of its own deprecations there
            text=True,
        )
        try:
            assert process.stdout is not None
            assert process.stdout.readline().strip() == "ready"
            yield gateway_end
        finally:
            process.terminate()
            process.communicate(timeout=10)


class LineCollector:
    """Reads a pipe on a thread, so the child never blocks on a full pipe; lines kept in order."""

    def __init__(self, stream: Any) -> None:
        self.lines: list[str] = []
        self._changed = threading.Condition()
        self._thread = threading.Thread(target=self._read, args=(stream,), daemon=True)
        self._thread.start()

    def _read(self, stream: Any) -> None:
        for line in stream:
            with self._changed:
                self.lines.append(line.rstrip("\n"))
                self._changed.notify_all()

    def wait_for(self, text: str, timeout_s: float = START_TIMEOUT_S) -> str:
        def found() -> str | None:
            return next((line for line in self.lines if text in line), None)

        with self._changed:
            if not self._changed.wait_for(lambda: found() is not None, timeout_s):
                raise AssertionError(f"{text!r} not seen within {timeout_s} s: {self.text}")
        line = found()
        assert line is not None
        return line

    def count(self, text: str) -> int:
        with self._changed:
            return sum(text in line for line in self.lines)

    def wait_for_count(self, text: str, count: int, timeout_s: float = START_TIMEOUT_S) -> None:
        """Until `count` lines (or more) contain `text`."""

        def enough() -> bool:
            return sum(text in line for line in self.lines) >= count

        with self._changed:
            if not self._changed.wait_for(enough, timeout_s):
                raise AssertionError(
                    f"{text!r} not seen {count} times in {timeout_s} s: {self.text}"
                )

    @property
    def text(self) -> str:
        return "\n".join(self.lines)

    def join(self, timeout_s: float = 5.0) -> None:
        self._thread.join(timeout_s)


class GatewayProcess:
    """`invt-gateway run --config FILE` with its log collected from stderr."""

    def __init__(
        self,
        config: dict[str, Any],
        directory: Path,
        env: Mapping[str, str] | None = None,
        command: Sequence[str] = (),
    ) -> None:
        """`command`: what runs instead of the `invt-gateway` script (its arguments follow)."""
        self.config_file = directory / f"gateway-{config.get('gateway_id', 'test')}.yaml"
        self.config_file.write_text(yaml.safe_dump(config), encoding="utf-8")
        self.process = subprocess.Popen(
            [*(command or [entry_point()]), "run", "--config", str(self.config_file)],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
            env={**os.environ, **(env or {})},
            # Pytest killed (a CI timeout): an orphaned gateway would go on reopening its pty
            # path, and lock the pty the kernel gives the next run's simulated line that number.
            preexec_fn=die_with_parent(),
        )
        assert self.process.stderr is not None
        self.log = LineCollector(self.process.stderr)

    def wait_ready(self, timeout_s: float = START_TIMEOUT_S) -> None:
        self.log.wait_for("ready:", timeout_s)

    def signal(self, signum: signal.Signals) -> None:
        self.process.send_signal(signum)

    def wait(self, timeout_s: float) -> int:
        code = self.process.wait(timeout_s)
        self.log.join()
        return code

    def stop(self) -> None:
        end(self.process, self.log)


def end(process: subprocess.Popen[str], *collectors: LineCollector) -> None:
    """A child ended as a service manager ends it (SIGTERM, SIGKILL 5 s later), what it wrote
    read to the end (`collectors`), its pipes closed."""
    if process.poll() is None:
        process.terminate()
        try:
            process.wait(5)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(5)
    for collector in collectors:
        collector.join()
    for stream in (process.stdin, process.stdout, process.stderr):
        if stream is not None:
            stream.close()


@contextlib.contextmanager
def gateway_process(
    config: dict[str, Any],
    directory: Path,
    env: Mapping[str, str] | None = None,
    command: Sequence[str] = (),
) -> Iterator[GatewayProcess]:
    gateway = GatewayProcess(config, directory, env, command)
    try:
        yield gateway
    finally:
        gateway.stop()


class SimulatorProcess:
    """`invt-gateway simulate --pty ...`: the device paths are its first lines on stdout (one,
    or one per master with `--masters N`); with `control`, its control commands go to its
    stdin (`SharedLine`)."""

    def __init__(self, args: Sequence[str], paths: int = 1, control: bool = False) -> None:
        self.process = subprocess.Popen(
            [entry_point(), "simulate", "--pty", *args],
            stdin=subprocess.PIPE if control else subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            preexec_fn=die_with_parent(),
        )
        assert self.process.stdout is not None
        assert self.process.stderr is not None
        self.output = LineCollector(self.process.stdout)
        self.errors = LineCollector(self.process.stderr)
        deadline = time.monotonic() + START_TIMEOUT_S
        while len(self.output.lines) < paths:
            if self.process.poll() is not None or time.monotonic() > deadline:
                raise AssertionError(f"simulator did not start: {self.errors.text}")
            time.sleep(0.01)  # polled with a deadline: another process's first lines
        self.paths = self.output.lines[:paths]
        self.path = self.paths[0]

    def stop(self) -> None:
        end(self.process, self.output, self.errors)


@contextlib.contextmanager
def simulator_process(*args: str) -> Iterator[SimulatorProcess]:
    simulator = SimulatorProcess(args)
    try:
        yield simulator
    finally:
        simulator.stop()


def descendants(pid: int) -> set[int]:
    """The processes `pid` started, and theirs, from /proc."""
    found: set[int] = set()
    for task in Path(f"/proc/{pid}/task").glob("*"):
        with contextlib.suppress(OSError):
            for child in (task / "children").read_text().split():
                found |= {int(child)} | descendants(int(child))
    return found


def _running(pid: int) -> bool:
    """Whether `pid` still runs: a zombie (ended, not yet reaped by whoever adopted it) does not."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def assert_ending_leaves_nothing_behind(
    command: Sequence[str], children: int, signum: signal.Signals = signal.SIGTERM
) -> None:
    """Start `command`; once it has started `children` processes, end it with `signum`: SIGTERM
    (as `timeout` or a CI runner would) or SIGKILL (`kill -9`, the OOM killer), which runs none
    of its code. Every process it started must be gone soon after."""
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    started: set[int] = set()
    try:
        deadline = time.monotonic() + 60
        while len(started) < children and time.monotonic() < deadline:
            time.sleep(0.2)  # waiting for processes another process starts: nothing to await
            started = descendants(process.pid)
        assert len(started) >= children, f"it started {len(started)} of {children} processes"
        process.send_signal(signum)
        assert process.wait(timeout=30) != 0
    finally:
        process.kill()
        process.wait()
    # A gateway stops within 2 s of SIGTERM; a generous bound for a loaded machine.
    deadline = time.monotonic() + 15
    left = {pid for pid in started if _running(pid)}
    while left and time.monotonic() < deadline:
        time.sleep(0.2)
        left = {pid for pid in left if _running(pid)}
    assert not left, f"still running after it ended: {_commands(left)}"


def command_of(pid: int) -> str:
    """Its command line, "" once it has gone."""
    with contextlib.suppress(OSError):
        return Path(f"/proc/{pid}/cmdline").read_text().replace("\0", " ").strip()
    return ""


def _commands(pids: set[int]) -> list[str]:
    return [command for command in map(command_of, sorted(pids)) if command]
