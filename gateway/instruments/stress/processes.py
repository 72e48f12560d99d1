"""The simulated line, the gateway and a Mosquitto broker as subprocesses the scenario can
unplug, kill and restart; the gateway's memory read from /proc."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml

from gateway.instruments.bench.processes import (
    SimulatorProcess,
    free_port,
    gateway_command,
    stop_process,
    wait_listening,
)
from gateway.instruments.die_with_parent import die_with_parent

START_TIMEOUT_S = 15.0
MOSQUITTO_PATHS = ("/usr/sbin/mosquitto", "/usr/local/sbin/mosquitto")


def launch_simulator(arguments: list[str]) -> subprocess.Popen[str]:
    """`invt-gateway simulate --pty ARGUMENTS`: commands on its stdin, the path its first line
    (`simulator_started`). From the main thread (`die_with_parent`)."""
    return subprocess.Popen(
        [*gateway_command(), "simulate", "--pty", *arguments],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
        preexec_fn=die_with_parent(),
    )


def simulator_started(process: subprocess.Popen[str]) -> SimulatorProcess:
    """Once the simulator has said its path (blocks; it is stopped if it says none)."""
    assert process.stdout is not None
    path = process.stdout.readline().strip()
    if not path.startswith("/"):
        stop_process(process)
        raise RuntimeError(f"the simulator did not start: {path!r}")
    return SimulatorProcess(process, [path])


class Gateway:
    """`invt-gateway run` on a configuration file; killed and started again at will."""

    def __init__(
        self,
        config: dict[str, Any],
        directory: Path,
        environment: Mapping[str, str] | None = None,
    ) -> None:
        self.port = int(config["modbus_tcp"]["port"])
        self.environment = dict(environment or {})
        """Variables set for it besides ours (`INVT_GATEWAY_TRACEMALLOC`)."""
        self.config_file = directory / "gateway.yaml"
        self.config_file.write_text(yaml.safe_dump(config), encoding="utf-8")
        self.log_file = directory / "gateway.log"
        self.process: subprocess.Popen[bytes] | None = None
        self.starts = 0

    def start(self) -> None:
        """From the main thread (`die_with_parent`)."""
        with self.log_file.open("ab") as log:
            self.process = subprocess.Popen(
                [*gateway_command(), "run", "--config", str(self.config_file)],
                stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,
                stderr=log,
                env={**os.environ, **self.environment},
                preexec_fn=die_with_parent(),
            )
        self.starts += 1

    def wait_listening(self, timeout_s: float = START_TIMEOUT_S) -> None:
        assert self.process is not None
        wait_listening(self.port, self.process, timeout_s)

    def kill(self) -> None:
        """SIGKILL: no shutdown, no last words; the kernel closes its port and sockets."""
        if self.process is not None and self.process.poll() is None:
            self.process.send_signal(signal.SIGKILL)
            self.process.wait(5)

    def stop(self) -> None:
        if self.process is not None:
            stop_process(self.process)

    def memory_mb(self) -> tuple[float, float]:
        """(resident now, peak resident) of the running process, in MB."""
        assert self.process is not None
        values = {}
        for line in Path(f"/proc/{self.process.pid}/status").read_text().splitlines():
            key, _, rest = line.partition(":")
            if key in ("VmRSS", "VmHWM"):
                values[key] = int(rest.split()[0]) / 1024
        return values.get("VmRSS", 0.0), values.get("VmHWM", 0.0)

    def log_tail(self, lines: int = 20) -> str:
        try:
            return "\n".join(self.log_file.read_text(errors="replace").splitlines()[-lines:])
        except OSError:
            return ""


def mosquitto_path() -> str | None:
    found = shutil.which("mosquitto")
    if found:
        return found
    return next((path for path in MOSQUITTO_PATHS if os.access(path, os.X_OK)), None)


class Broker:
    """A Mosquitto of our own on a free port; killed and started again on the same port."""

    def __init__(self, executable: str, directory: Path) -> None:
        self.executable = executable
        self.host = "127.0.0.1"
        self.port = free_port()
        self.config_file = directory / "mosquitto.conf"
        # Started as root, Mosquitto would become user "mosquitto", and the kernel forgets a
        # process's parent-death signal when its user changes (`die_with_parent`).
        user = "user root\n" if os.geteuid() == 0 else ""
        self.config_file.write_text(
            f"{user}listener {self.port} {self.host}\nallow_anonymous true\n"
            "persistence false\nlog_dest none\n",
            encoding="utf-8",
        )
        self.process: subprocess.Popen[bytes] | None = None

    def start(self) -> None:
        """From the main thread (`die_with_parent`); `wait_listening` then says it is up."""
        self.process = subprocess.Popen(
            [self.executable, "-c", str(self.config_file)],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            preexec_fn=die_with_parent(),
        )

    def wait_listening(self) -> None:
        assert self.process is not None
        wait_listening(self.port, self.process, START_TIMEOUT_S)

    def kill(self) -> None:
        if self.process is not None and self.process.poll() is None:
            self.process.kill()
            self.process.wait(5)

    def stop(self) -> None:
        if self.process is not None:
            stop_process(self.process)
