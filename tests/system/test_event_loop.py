"""The event loop a real `invt-gateway run` process picks: uvloop where it is installed (it does
the loop's work in C: fewer instructions per bus transaction), asyncio's own where it isn't or
when `INVT_GATEWAY_EVENT_LOOP=asyncio` asks for it. Whichever it is, the log and the build info
metric say so and the drives answer alike; a name it doesn't know stops it before it starts."""

from __future__ import annotations

import asyncio
import os
import platform
import subprocess
import sys
import urllib.request
from pathlib import Path
from typing import Any

import pytest
import yaml
from prometheus_client.parser import text_string_to_metric_families

from gateway import ENGINE_ROOM
from gateway.exit_codes import EXIT_CONFIG
from gateway.instruments.simulator import SimulatedLine
from tests.support import TcpClient, free_port
from tests.support.processes import gateway_process, run_cli

STATE_WORD_1 = 0x2100
STOPPED = 3

WITHOUT_UVLOOP = [
    sys.executable,
    "-c",
    # As on a machine where uvloop has no wheel: its import fails.
    "import sys; sys.modules['uvloop'] = None; from gateway.cli import main; "
    "raise SystemExit(main(sys.argv[1:]))",
]


def config(port: str, tcp_port: int, metrics_port: int) -> dict[str, Any]:
    return {
        "gateway_id": "loop-test",
        "modbus_tcp": {"host": "127.0.0.1", "port": tcp_port},
        "buses": [{"name": "line1", "port": port, "baudrate": 115200, "timeout_ms": 300}],
        "drives": [
            {"name": "pump1", "bus": "line1", "address": 1, "model": "gd350"},
            {"name": "fan2", "bus": "line1", "address": 2, "model": "gd20"},
        ],
        "metrics": {"enabled": True, "host": "127.0.0.1", "port": metrics_port},
    }


def build_info(metrics_port: int) -> dict[str, str]:
    with urllib.request.urlopen(f"http://127.0.0.1:{metrics_port}/metrics", timeout=5) as reply:
        text = reply.read().decode()
    for family in text_string_to_metric_families(text):
        if family.name == "invt_gateway_build_info":
            return dict(family.samples[0].labels)
    raise AssertionError("no invt_gateway_build_info in /metrics")


async def serve_and_check(
    line: SimulatedLine, tmp_path: Path, env: dict[str, str], command: list[str] | None = None
) -> tuple[str, dict[str, str]]:
    """Start the gateway, read both drives' state words through it 50 times; its log, and the
    build info labels."""
    tcp_port, metrics_port = free_port(), free_port()
    with gateway_process(
        config(line.path, tcp_port, metrics_port), tmp_path, env, command or ()
    ) as gateway:
        await asyncio.to_thread(gateway.wait_ready)
        client = await TcpClient.connect(tcp_port)
        try:
            for _ in range(50):
                for unit in (1, 2):
                    assert await client.read(unit, STATE_WORD_1) == [STOPPED]
        finally:
            await client.close()
        info = await asyncio.to_thread(build_info, metrics_port)
        return gateway.log.text, info


@pytest.mark.line(addresses=[1, 2])
async def test_the_service_runs_on_uvloop_where_it_is_installed(
    line: SimulatedLine, tmp_path: Path
) -> None:
    uvloop = pytest.importorskip("uvloop")  # not where it has no wheel (32-bit ARM)
    log, info = await serve_and_check(line, tmp_path, {"INVT_GATEWAY_EVENT_LOOP": "auto"})
    assert f"event loop: uvloop {uvloop.__version__}" in log
    # How the engine room runs, beside it: the gateway process imports the package as this one.
    assert f"engine room: {ENGINE_ROOM}" in log
    assert info["event_loop"] == "uvloop"
    assert info["python"] == platform.python_version()
    assert info["gateway_id"] == "loop-test"


@pytest.mark.line(addresses=[1, 2])
async def test_asked_for_asyncio_it_runs_on_asyncio_s_own_loop(
    line: SimulatedLine, tmp_path: Path
) -> None:
    log, info = await serve_and_check(line, tmp_path, {"INVT_GATEWAY_EVENT_LOOP": "asyncio"})
    assert (
        f"event loop: asyncio {platform.python_version()} (INVT_GATEWAY_EVENT_LOOP=asyncio)" in log
    )
    assert info["event_loop"] == "asyncio"


@pytest.mark.line(addresses=[1, 2])
async def test_without_uvloop_it_runs_on_asyncio_and_says_why(
    line: SimulatedLine, tmp_path: Path
) -> None:
    log, info = await serve_and_check(
        line, tmp_path, {"INVT_GATEWAY_EVENT_LOOP": "auto"}, WITHOUT_UVLOOP
    )
    assert f"event loop: asyncio {platform.python_version()} (uvloop not installed)" in log
    assert info["event_loop"] == "asyncio"


def valid_config_file(tmp_path: Path) -> Path:
    """A configuration that validates (the loop is chosen after it is read)."""
    path = tmp_path / "gateway.yaml"
    path.write_text(yaml.safe_dump(config("/dev/ttyUSB0", free_port(), free_port())))
    return path


def test_uvloop_asked_for_but_missing_stops_it_naming_the_variable(tmp_path: Path) -> None:
    done = subprocess.run(
        [*WITHOUT_UVLOOP, "run", "--config", str(valid_config_file(tmp_path))],
        capture_output=True,
        text=True,
        timeout=30,
        env={**os.environ, "INVT_GATEWAY_EVENT_LOOP": "uvloop"},
        check=False,
    )
    assert done.returncode == EXIT_CONFIG, done.stderr
    assert "INVT_GATEWAY_EVENT_LOOP: uvloop asked for, but it doesn't import" in done.stderr


@pytest.mark.parametrize("command", ["run", "demo"])
def test_a_loop_it_does_not_know_stops_it_before_it_starts(tmp_path: Path, command: str) -> None:
    args = (
        [command, "--config", str(valid_config_file(tmp_path))] if command == "run" else [command]
    )
    done = run_cli(*args, env={"INVT_GATEWAY_EVENT_LOOP": "trio"})
    assert done.returncode == EXIT_CONFIG, done.stderr
    assert "INVT_GATEWAY_EVENT_LOOP: 'trio' is not one of auto, uvloop, asyncio" in done.stderr
