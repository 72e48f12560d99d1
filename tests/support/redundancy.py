"""Two redundant gateway boxes as the redundancy tests run them (`invt-gateway run` each, with
its own file, store and control socket), and the coordinator's part played through `invt-gateway
role` and Keepalived's notify script (`config/invt-gateway-notify.sh`).

The fixtures the tests share, imported by name into a test module (`from
tests.support.redundancy import boxes as boxes, line as line`): `line`, the simulated line two
boxes share (drive 1 on it), and `boxes`, the boxes a test starts, stopped at its end."""

from __future__ import annotations

import asyncio
import json
import os
import re
import subprocess
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import pytest

from tests.support import free_port, read_state_word
from tests.support.http import http_get
from tests.support.mosquitto import Mosquitto, unique_base_topic
from tests.support.processes import ROOT, GatewayProcess, entry_point, run_cli
from tests.support.shared_line import SharedLine, shared_line

POLL_MS = 200
"""The drive's state polled five times a second: the active is heard all the time."""
SILENCE_S = 1.0
"""Derived (`derived_silence_s`): 3 x 0.2 s + 0.1 s x 2 attempts = 0.8 s, at least 1 s."""
TAKEOVER_BOUND_S = 3.0
NOTIFY = ROOT / "config" / "invt-gateway-notify.sh"
STATE_WORD_1 = 0x2100


def box_config(
    line: str, folder: Path, role: str, hold_off_ms: float, box: str, **more: Any
) -> dict[str, Any]:
    folder.mkdir(exist_ok=True)
    return {
        "gateway_id": "pair",  # both boxes alike: one gateway, on two boxes
        "modbus_tcp": {"host": "127.0.0.1", "port": 0},  # `more` may say otherwise
        "buses": [{"name": "line1", "port": line, "timeout_ms": 100, "retries": 1}],
        "drives": [
            {
                "name": "pump",
                "bus": "line1",
                "address": 1,
                "model": "gd350",
                "poll": [
                    {"name": "state", "start": STATE_WORD_1, "count": 3, "interval_ms": POLL_MS}
                ],
            }
        ],
        "storage": {"path": str(folder / "events.db")},
        "redundancy": {
            "enabled": True,
            "role": role,
            "box": box,
            "peer": "the other box",
            "hold_off_ms": hold_off_ms,
            "fault_file": str(folder / "fault"),  # Keepalived's track_file (its test reads it)
        },
        "metrics": {"enabled": True, "host": "127.0.0.1", "port": free_port()},
        **more,
    }


class Box:
    """One gateway box: its process, its Modbus-TCP port, its role asked and read."""

    def __init__(
        self,
        name: str,
        line: str,
        folder: Path,
        role: str,
        hold_off_ms: float = 0.0,
        command: Sequence[str] = (),
        **more: Any,
    ) -> None:
        """`command`: what runs `invt-gateway` (`ip netns exec NS invt-gateway`: a box of its
        own on the network); `more`: sections of its file besides the test's own."""
        self.name = name
        config = box_config(line, folder / name, role, hold_off_ms, name, **more)
        self.metrics_port = int(config["metrics"]["port"])
        self.metrics_host = str(config["metrics"]["host"])
        self.gateway = GatewayProcess(config, folder / name, command=command)
        self.gateway.wait_ready()
        ready = self.gateway.log.wait_for("ready:")
        found = re.search(r"Modbus-TCP on [^ ]+:(\d+)", ready)
        assert found is not None, ready
        self.tcp_port = int(found.group(1))

    @property
    def config(self) -> str:
        return str(self.gateway.config_file)

    @property
    def fault_file(self) -> Path:
        """`redundancy.fault_file`: 0 while this box can be the line's master, 1 once not."""
        return self.gateway.config_file.parent / "fault"

    def says_unfit(self) -> bool:
        """The fault file says 1 (what Keepalived's track_file reads at once)."""
        try:
            return self.fault_file.read_text().strip() == "1"
        except FileNotFoundError:
            return False

    def ask(self, role: str) -> str:
        done = run_cli("role", role, "--config", self.config, timeout_s=15)
        assert done.returncode == 0, done.stderr
        return done.stdout.strip()

    def notified(self, state: str) -> str:
        """Keepalived's notify script run on this box for VRRP `state` (MASTER, BACKUP, ...),
        as keepalived runs it; what it logged."""
        done = subprocess.run(
            [str(NOTIFY), "INSTANCE", "invt_gateway", state, "150"],
            env={**os.environ, "CONFIG": self.config, "GATEWAY": entry_point(), "UNIT": "none"},
            capture_output=True,
            text=True,
            timeout=15,
            check=False,
        )
        assert done.returncode == 0, done.stderr
        return done.stderr

    def status(self) -> dict[str, Any]:
        """`role status`'s JSON (its exit code 1 when the box is unfit: `check_fails`)."""
        done = run_cli("role", "status", "--config", self.config, timeout_s=15)
        assert done.returncode in (0, 1), done.stderr
        assert done.stdout, done.stderr
        status: dict[str, Any] = json.loads(done.stdout.splitlines()[0])
        return status

    def check_fails(self) -> bool:
        """Keepalived's track script (`invt-gateway-notify.sh check`) fails on this box."""
        done = subprocess.run(
            [str(NOTIFY), "check"],
            env={**os.environ, "CONFIG": self.config, "GATEWAY": entry_point(), "UNIT": "none"},
            capture_output=True,
            text=True,
            timeout=15,
            check=False,
        )
        return done.returncode != 0

    def wait_role(self, role: str, within_s: float) -> dict[str, Any]:
        deadline = time.monotonic() + within_s
        while True:
            status = self.status()
            if status["role"] == role:
                return status
            assert time.monotonic() < deadline, f"{self.name} not {role}: {status}"
            time.sleep(0.1)  # another process's state: polled with a deadline

    def health(self) -> dict[str, Any]:
        _, _, body = asyncio.run(http_get(self.metrics_port, "/health", self.metrics_host))
        health: dict[str, Any] = json.loads(body)
        return health

    def metrics(self) -> str:
        _, _, body = asyncio.run(http_get(self.metrics_port, "/metrics", self.metrics_host))
        return body

    def read_state(self) -> bytes:
        return read_state_word(self.tcp_port, 1)

    def stop(self) -> None:
        self.gateway.stop()


def start_pair(
    boxes: list[Box],
    paths: Sequence[str],
    folder: Path,
    a: dict[str, Any] | None = None,
    b: dict[str, Any] | None = None,
    **more: Any,
) -> tuple[Box, Box]:
    """Box a started active on `paths[0]`, box b standby on `paths[1]` (each with its own
    sections `a` and `b` of its file, both with `more`), appended to `boxes`; (a, b) once box a
    has taken the line."""
    boxes.append(active := Box("a", paths[0], folder, "active", **(a or {}), **more))
    boxes.append(standby := Box("b", paths[1], folder, "standby", **(b or {}), **more))
    active.wait_role("active", 5.0)
    return active, standby


def pair_broker(mosquitto: Mosquitto, **more: Any) -> tuple[str, str, dict[str, Any]]:
    """Both boxes' `mqtt:` section, `mosquitto` under a base topic of the test's own (`more`
    besides): (the base topic, the events' topic, the section)."""
    base = unique_base_topic("pair")
    broker = {"host": mosquitto.host, "port": mosquitto.port, "base_topic": base, **more}
    return base, f"{base}/bridge/event", broker


def frames(line: SharedLine) -> list[int]:
    return [master["frames"] for master in line.stats()["masters"]]


@pytest.fixture
def line() -> Iterator[SharedLine]:
    """One line two boxes share (`simulate --masters 2`), drive 1 on it."""
    with shared_line(2, "--address", "1") as shared:
        yield shared


@pytest.fixture
def boxes() -> Iterator[list[Box]]:
    """The boxes a test starts (it appends them), stopped at its end."""
    started: list[Box] = []
    yield started
    for box in started:
        box.stop()
