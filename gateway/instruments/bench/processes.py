"""The simulated line and the gateway as real subprocesses, measured from /proc."""

from __future__ import annotations

import contextlib
import functools
import json
import math
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from gateway.instruments.die_with_parent import die_with_parent

CLOCK_TICKS = os.sysconf("SC_CLK_TCK")
GATEWAY_NICENESS = -10
"""The systemd unit's `Nice=`: the bench runs the gateway as the service runs, where it may."""
PROFILE_VARIABLE = "INVT_BENCH_PROFILE"
"""Set to a file's path: the gateway runs under cProfile and writes its statistics there."""


@functools.cache
def niceness_prefix() -> tuple[str, ...]:
    """`nice -n -10` if this user may raise a process's priority (root, CAP_SYS_NICE); else
    nothing, and the gateway runs at the bench's own niceness."""
    nice = shutil.which("nice")
    if nice is None:
        return ()
    command = (nice, "-n", str(GATEWAY_NICENESS))
    # GNU nice runs the command anyway when refused, and says so on stderr.
    tried = subprocess.run([*command, "true"], capture_output=True, text=True, check=False)
    return command if tried.returncode == 0 and not tried.stderr else ()


def gateway_niceness() -> str:
    """How the gateway's priority is set, in words, for the bench's report."""
    if niceness_prefix():
        return f"at nice {GATEWAY_NICENESS}, as its systemd unit runs it (the simulated drives too)"
    return f"at this shell's niceness (its systemd unit's nice {GATEWAY_NICENESS} needs root)"


def gateway_command() -> list[str]:
    return [sys.executable, "-m", "gateway"]


@dataclass
class SimulatorProcess:
    process: subprocess.Popen[str]
    paths: list[str]
    """One per line it serves."""

    @property
    def path(self) -> str:
        """Its first line's."""
        return self.paths[0]

    def command(self, text: str) -> str:
        assert self.process.stdin is not None
        assert self.process.stdout is not None
        self.process.stdin.write(text + "\n")
        self.process.stdin.flush()
        return self.process.stdout.readline().strip()

    def cpu_s(self) -> float:
        return cpu_s(self.process.pid)

    def run_queue_s(self) -> float:
        return run_queue_s(self.process.pid)

    def stats(self, line: int = 1) -> dict[str, Any]:
        """The counters of its `line`-th line (from 1)."""
        answer = self.command(f"line {line} stats")
        if not answer.startswith("ok"):
            raise RuntimeError(f"simulator refused stats of line {line}: {answer}")
        result: dict[str, Any] = json.loads(answer.removeprefix("ok").strip())
        return result

    @property
    def lines(self) -> list[SimulatorLine]:
        return [SimulatorLine(self, number, path) for number, path in enumerate(self.paths, 1)]


@dataclass(frozen=True)
class SimulatorLine:
    """One of the lines a simulator process serves."""

    simulator: SimulatorProcess
    number: int
    path: str

    def stats(self) -> dict[str, Any]:
        return self.simulator.stats(self.number)


@contextlib.contextmanager
def simulator(
    addresses: list[int],
    baudrate: int,
    dead: list[int],
    response_delay_ms: float,
    extra_args: Sequence[str] = (),
    lines: int = 1,
) -> Iterator[SimulatorProcess]:
    """`simulate` serving `lines` lines alike (each with `addresses`), in one process, at the
    gateway's priority: the drives it stands for have processors of their own, and a machine
    busy with other work must not make them answer late (115200, fast drives behind a relay:
    replies 135-277 us late on average at the default priority, 47-212 us at the gateway's;
    the bench counted that lateness of the harness against the gateway)."""
    simulate = ["simulate", "--pty", "--baud", str(baudrate), *extra_args]
    args = [*niceness_prefix(), *gateway_command(), *simulate]
    args += ["--response-delay-ms", str(response_delay_ms), "--lines", str(lines)]
    for address in addresses:
        args += ["--address", str(address)]
    for address in dead:
        args += ["--dead", str(address)]
    process = subprocess.Popen(
        args,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        preexec_fn=die_with_parent(),
    )
    try:
        assert process.stdout is not None
        paths = [process.stdout.readline().strip() for _ in range(lines)]
        if not all(path.startswith("/") for path in paths):
            raise RuntimeError(f"simulator did not start: {paths!r}")
        yield SimulatorProcess(process, paths)
    finally:
        stop_process(process)


def cpu_s(pid: int) -> float:
    """The CPU time (user and system) the process `pid` has had."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    # utime and stime are fields 14 and 15 of stat; index 11 and 12 after the ")".
    return (int(fields[11]) + int(fields[12])) / CLOCK_TICKS


def processors() -> int:
    """The machine's processors, as /proc/stat counts them (its steal is theirs together): the
    page's Machine line and the cases' steal share both take this."""
    return os.cpu_count() or 1


def host_steal_s() -> float:
    """CPU time the hypervisor gave other machines while this one's processors wanted it, all
    processors together, since boot (steal, /proc/stat): nan where the kernel doesn't count it.
    On a busy host a few percent of it make every wake-up late, whoever runs here."""
    try:
        with open("/proc/stat") as stat:
            fields = stat.readline().split()
        # "cpu user nice system idle iowait irq softirq steal ...": steal is the 8th number.
        return int(fields[8]) / CLOCK_TICKS
    except (OSError, IndexError, ValueError):
        return math.nan


def run_queue_s(pid: int) -> float:
    """How long the threads of `pid` have waited on a run queue, runnable but not running (a
    machine busy with other work): nan where the kernel doesn't keep schedstat."""
    waited = 0
    try:
        for task in Path(f"/proc/{pid}/task").iterdir():
            # schedstat: time on the CPU, time waiting on a run queue (ns), timeslices.
            waited += int((task / "schedstat").read_text().split()[1])
    except (OSError, IndexError, ValueError):
        return math.nan
    return waited / 1e9


@dataclass
class GatewayProcess:
    process: subprocess.Popen[bytes]
    port: int

    def cpu_s(self) -> float:
        return cpu_s(self.process.pid)

    def run_queue_s(self) -> float:
        return run_queue_s(self.process.pid)

    def peak_rss_mb(self) -> float:
        """The most resident memory it has had, in MiB."""
        return self._status_mib("VmHWM:")

    def rss_mb(self) -> float:
        """Its resident memory now, in MiB."""
        return self._status_mib("VmRSS:")

    def _status_mib(self, field: str) -> float:
        for line in Path(f"/proc/{self.process.pid}/status").read_text().splitlines():
            if line.startswith(field):
                return int(line.split()[1]) / 1024
        return 0.0


@contextlib.contextmanager
def gateway(
    config: dict[str, Any],
    port: int,
    prefix: Sequence[str] = (),
    start_timeout_s: float = 15.0,
    stop_timeout_s: float = 5.0,
    cwd: str | None = None,
) -> Iterator[GatewayProcess]:
    """The gateway with `config`, listening on `port`; stopped (SIGTERM) when the block ends.

    `prefix` runs it under another program (e.g. valgrind), which may need longer to start
    and, at exit, to write what it gathered: hence the timeouts. `cwd`: the folder it runs
    in, whose `gateway` package `python -m` imports first (another checkout's, to compare).
    """
    with tempfile.TemporaryDirectory(prefix="invt-bench-") as folder:
        path = Path(folder) / "config.yaml"
        if "storage" not in config:
            # A store of its own: the box's default (`events-<gateway_id>.db` in the state
            # directory) is held by any other gateway of that id, a bench beside this one or a
            # case's gateway still stopping, and a second opener is refused at start (exit 4).
            config = {**config, "storage": {"path": str(Path(folder) / "events.db")}}
        path.write_text(yaml.safe_dump(config))
        command = gateway_command()
        if profile := os.environ.get(PROFILE_VARIABLE):
            # The gateway under cProfile, its statistics written at its (graceful) exit.
            command = [sys.executable, "-m", "cProfile", "-o", profile, "-m", "gateway"]
        process = subprocess.Popen(
            [*niceness_prefix(), *prefix, *command, "run", "--config", str(path)],
            cwd=cwd,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            preexec_fn=die_with_parent(),
        )
        try:
            wait_listening(port, process, start_timeout_s)
            yield GatewayProcess(process, port)
        finally:
            stop_process(process, stop_timeout_s)


MAX_HANDED_OUT = 4096
_HANDED_OUT: set[int] = set()
"""The ports `free_port` gave in this process: the kernel's choice for a bind to port 0 can be
the same port twice in a row (1 pair in 5,000 here), and a caller taking two (a demo's
Modbus-TCP and MQTT ports) then found its own first listener on the second."""


def free_port() -> int:
    """A loopback TCP port nothing listens on now, and one this process wasn't given before."""
    while True:
        with socket.socket() as sock:
            sock.bind(("127.0.0.1", 0))
            port = int(sock.getsockname()[1])
        if port not in _HANDED_OUT:
            if len(_HANDED_OUT) >= MAX_HANDED_OUT:
                _HANDED_OUT.clear()  # long gone by now; the range is some 28,000 ports
            _HANDED_OUT.add(port)
            return port


def wait_listening(port: int, process: subprocess.Popen[Any], timeout_s: float = 15.0) -> None:
    """Until something accepts on `port`; RuntimeError if `process` exits first or time runs out."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if process.poll() is not None:
            raise RuntimeError(f"{process.args!r} exited with {process.returncode} at start")
        with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", port), 0.2):
            return
        time.sleep(0.02)
    raise RuntimeError(f"nothing listens on port {port} after {timeout_s:.0f} s")


def stop_process(process: subprocess.Popen[Any], timeout_s: float = 5.0) -> None:
    """SIGTERM, then SIGKILL after `timeout_s`; its pipes drained and closed either way."""
    if process.poll() is None:
        process.terminate()
        try:
            process.communicate(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            process.kill()
            process.communicate()
    else:
        process.communicate()
