"""A three-node NATS Server cluster with its MQTT listeners, on free loopback ports, whose nodes
can be SIGKILLed and started again: what `invt-gateway stress --cluster` runs its gateways on,
and the suite's cluster test too (`tests.support.nats`).

Debian's `nats-server` (2.9) speaks MQTT 3.1.1 on JetStream: retained messages and persistent
sessions are kept in streams replicated on every node (`stream_replicas: 3`), so one node's
death loses neither. A node started again keeps its ports and its store folder, and rejoins.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import shutil
import socket
import subprocess
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from gateway.instruments.bench.processes import free_port
from gateway.instruments.die_with_parent import die_with_parent

NATS_SERVER_PATHS = ("/usr/sbin/nats-server", "/usr/bin/nats-server")
START_TIMEOUT_S = 10.0
SERVING_TIMEOUT_S = 20.0
"""A node's MQTT listener answers before JetStream (its sessions' store) has a leader."""


def nats_server_path() -> str | None:
    """The nats-server executable (Debian's package `nats-server`), or None."""
    found = shutil.which("nats-server")
    if found:
        return found
    return next((path for path in NATS_SERVER_PATHS if os.access(path, os.X_OK)), None)


@dataclass
class NatsNode:
    name: str
    directory: Path
    executable: str = field(default_factory=lambda: nats_server_path() or NATS_SERVER_PATHS[0])
    host: str = "127.0.0.1"
    client_port: int = field(default_factory=free_port)
    cluster_port: int = field(default_factory=free_port)
    port: int = field(default_factory=free_port)
    """The MQTT listener's (what a gateway connects to)."""
    kills: int = 0
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
            f"cluster {{ name: invt-cluster, listen: {self.host}:{self.cluster_port}, "
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
        """From the main thread (`die_with_parent`: a run killed outright takes its nodes)."""
        with self.log_file.open("ab") as log:
            self._process = subprocess.Popen(
                [self.executable, "-c", str(self.config_file)],
                stdin=subprocess.DEVNULL,
                stdout=log,
                stderr=log,
                preexec_fn=die_with_parent(),
            )

    def wait_listening(self, timeout_s: float = START_TIMEOUT_S) -> None:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self._process is not None and self._process.poll() is not None:
                break
            with contextlib.suppress(OSError), socket.create_connection((self.host, self.port), 1):
                return
            time.sleep(0.05)  # polled with a deadline: another process's port
        raise RuntimeError(f"nats-server {self.name} did not listen on {self.port}: {self.log()}")

    async def wait_serving(self, timeout_s: float = SERVING_TIMEOUT_S) -> None:
        """Until the node takes an MQTT client (its JetStream has a leader to keep sessions)."""
        import aiomqtt  # the runtime's; imported here so the suite's helpers import without it

        deadline = time.monotonic() + timeout_s
        while True:
            try:
                async with aiomqtt.Client(
                    self.host, self.port, identifier=f"probe-{uuid.uuid4().hex[:8]}", timeout=5
                ):
                    return
            except aiomqtt.MqttError:
                if time.monotonic() > deadline:
                    raise RuntimeError(
                        f"nats-server {self.name} never took an MQTT client: {self.log()}"
                    ) from None
                await asyncio.sleep(0.2)

    def kill(self) -> None:
        """SIGKILL: no goodbye to its clients nor to the other nodes."""
        process, self._process = self._process, None
        if process is not None and process.poll() is None:
            process.kill()
            process.wait(5)
            self.kills += 1

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
    """`size` nodes routed to each other, each with JetStream and MQTT; stopped at the end.
    RuntimeError when nats-server is not installed or a node does not start."""
    executable = nats_server_path()
    if executable is None:
        raise RuntimeError("nats-server not found: install the Debian package nats-server")
    nodes = [NatsNode(f"n{index}", directory, executable) for index in range(size)]
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
