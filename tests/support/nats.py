"""A three-node NATS Server cluster with its MQTT listeners, on free loopback ports, whose nodes a
test can SIGKILL and start again.

Debian's `nats-server` (2.9) speaks MQTT 3.1.1 on JetStream: retained messages and persistent
sessions are kept in streams replicated on every node (`stream_replicas: 3`), so one node's
death loses neither. A test without nats-server is skipped, saying so.
"""

from __future__ import annotations

import contextlib
import shutil
import socket
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from tests.support import free_port

NATS_SERVER = shutil.which("nats-server") or "/usr/sbin/nats-server"
START_TIMEOUT_S = 10.0


@dataclass
class NatsNode:
    name: str
    directory: Path
    host: str = "127.0.0.1"
    client_port: int = field(default_factory=free_port)
    cluster_port: int = field(default_factory=free_port)
    port: int = field(default_factory=free_port)
    """The MQTT listener's (what a gateway connects to)."""
    _process: subprocess.Popen[bytes] | None = None

    @property
    def address(self) -> str:
        return f"{self.host}:{self.port}"

    @property
    def running(self) -> bool:
        return self._process is not None and self._process.poll() is None

    def write_config(self, routes: list[int]) -> None:
        store = self.directory / f"store-{self.name}"
        store.mkdir(parents=True, exist_ok=True)
        route_list = ", ".join(f"nats-route://{self.host}:{port}" for port in routes)
        self.config_file.write_text(
            f"server_name: {self.name}\n"
            f"listen: {self.host}:{self.client_port}\n"
            f'jetstream {{ store_dir: "{store}" }}\n'
            f"cluster {{ name: invt-test, listen: {self.host}:{self.cluster_port}, "
            f"routes: [{route_list}] }}\n"
            f"mqtt {{ listen: {self.host}:{self.port}, stream_replicas: 3 }}\n",
            encoding="utf-8",
        )

    @property
    def config_file(self) -> Path:
        return self.directory / f"nats-{self.name}.conf"

    @property
    def log_file(self) -> Path:
        return self.directory / f"nats-{self.name}.log"

    def start(self) -> None:
        log = self.log_file.open("ab")
        self._process = subprocess.Popen(
            [NATS_SERVER, "-c", str(self.config_file)], stdout=log, stderr=log
        )
        log.close()

    def wait_listening(self, timeout_s: float = START_TIMEOUT_S) -> None:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self._process is not None and self._process.poll() is not None:
                break
            with contextlib.suppress(OSError), socket.create_connection((self.host, self.port), 1):
                return
            time.sleep(0.05)  # polled with a deadline: another process's port
        raise RuntimeError(f"nats-server {self.name} did not listen on {self.port}: {self.log()}")

    def kill(self) -> None:
        """SIGKILL: no goodbye to its clients nor to the other nodes."""
        process, self._process = self._process, None
        if process is not None and process.poll() is None:
            process.kill()
            process.wait(5)

    def stop(self) -> None:
        process, self._process = self._process, None
        if process is not None and process.poll() is None:
            process.terminate()
            try:
                process.wait(5)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait(5)

    def log(self) -> str:
        try:
            return self.log_file.read_text(encoding="utf-8", errors="replace")[-3000:]
        except OSError:
            return ""


@contextlib.contextmanager
def nats_cluster(directory: Path, size: int = 3) -> Iterator[list[NatsNode]]:
    """`size` nodes routed to each other, each with JetStream and MQTT; stopped at the end."""
    if not Path(NATS_SERVER).exists():
        pytest.skip(f"{NATS_SERVER} not found: install the Debian package nats-server")
    nodes = [NatsNode(f"n{index}", directory) for index in range(size)]
    routes = [node.cluster_port for node in nodes]
    try:
        for node in nodes:
            node.write_config(routes)
            node.start()
        for node in nodes:
            node.wait_listening()
        yield nodes
    finally:
        for node in nodes:
            node.stop()
