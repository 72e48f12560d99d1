"""A serial device server between the gateway and the line: socat (nobody here wrote it) listens on
TCP and passes bytes to the drives' serial line, and the gateway's bus port is
`socket://host:port`, as the configuration reference offers for Ethernet-to-RS-485 converters.
The device server going away is a lost port: 0BH meanwhile, and the gateway is back when it is."""

from __future__ import annotations

import asyncio
import shutil
import subprocess
import time
from pathlib import Path

import pytest

from gateway.instruments.bench.processes import free_port, stop_process
from gateway.instruments.simulator import SimulatedLine
from tests.support import TcpClient, eventually, gateway_config, running_gateway

pytestmark = [
    pytest.mark.skipif(shutil.which("socat") is None, reason="socat not installed"),
    pytest.mark.line(baudrate=19200, parity="N"),
]


def device_server(line_path: str, port: int) -> subprocess.Popen[bytes]:
    """socat serving one TCP connection on `port` with the line's bytes, listening on return.

    Not probed by connecting (socat serves one connection, then exits): its listening socket is
    looked up in /proc/net/tcp instead."""
    process = subprocess.Popen(
        ["socat", f"TCP-LISTEN:{port},bind=127.0.0.1,reuseaddr", f"FILE:{line_path},raw,echo=0"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.monotonic() + 10
    while not listening(port):
        if process.poll() is not None or time.monotonic() > deadline:
            stop_process(process)
            raise RuntimeError(f"socat is not listening on port {port}")
        time.sleep(0.01)  # polled with a deadline: another process's socket
    return process


def listening(port: int) -> bool:
    rows = Path("/proc/net/tcp").read_text().splitlines()[1:]
    return any(
        row.split()[1].endswith(f":{port:04X}") and row.split()[3] == "0A"  # 0A: LISTEN
        for row in rows
    )


async def read_until_answered(client: TcpClient, unit: int, seconds: float) -> list[int]:
    deadline = asyncio.get_running_loop().time() + seconds
    while True:
        reply = await client.request(unit, bytes.fromhex("03 21 00 00 01"))
        if not reply[0] & 0x80:
            return [int.from_bytes(reply[2:4], "big")]
        assert reply == bytes.fromhex("83 0B")  # meanwhile: gateway target failed, nothing else
        assert asyncio.get_running_loop().time() < deadline, "not back in time"
        await asyncio.sleep(0.1)  # polled with a deadline: 0BH until the reopen backoff retries


async def test_drives_behind_a_serial_device_server(line: SimulatedLine) -> None:
    port = free_port()
    server = device_server(line.path, port)
    try:
        drives = [{"name": "pump1", "address": 1}, {"name": "fan2", "address": 2}]
        config = gateway_config(f"socket://127.0.0.1:{port}", drives, baudrate=19200, parity="N")
        async with running_gateway(config) as app:
            client = await TcpClient.connect(app.tcp.port)
            assert await client.read(1, 0x2100, 1) == [3]  # state word 1: stopped
            assert await client.read(2, 0x2100, 1) == [3]
            assert line.stats["gap_violations"] == 0

            # The converter loses power (in a thread: the gateway runs on this test's loop).
            await asyncio.to_thread(stop_process, server)
            line_ = app.buses["line1"].line
            await eventually(lambda: not line_.is_open, what="the connection's end seen")
            assert await client.request(1, bytes.fromhex("03 21 00 00 01")) == bytes.fromhex(
                "83 0B"
            )
            server = await asyncio.to_thread(device_server, line.path, port)  # and comes back
            assert await read_until_answered(client, 1, 10.0) == [3]
            assert app.buses["line1"].stats.reopens >= 1
            await client.close()
    finally:
        stop_process(server)


async def test_an_idle_line_behind_a_device_server_probes_a_drive_back(
    line: SimulatedLine,
) -> None:
    """No client asks anything: the bus's own probe still finds a drive that is back (the line
    is read only when the gateway reads it, so the idle wait must end for the probe to go)."""
    port = free_port()
    server = device_server(line.path, port)
    try:
        drives = [{"name": "pump1", "address": 1}, {"name": "fan2", "address": 2}]
        config = gateway_config(
            f"socket://127.0.0.1:{port}",
            drives,
            baudrate=19200,
            parity="N",
            timeout_ms=100,
            retries=0,
            offline_after=1,
        )
        line.set_dead(2, True)
        async with running_gateway(config) as app:
            bus = app.buses["line1"]
            client = await TcpClient.connect(app.tcp.port)
            assert await client.request(2, bytes.fromhex("03 21 00 00 01")) == bytes.fromhex(
                "83 0B"
            )
            assert bus.health.is_offline(2)
            line.set_dead(2, False)
            await eventually(
                lambda: not bus.health.is_offline(2), within_s=10.0, what="fan2 probed back"
            )
            await client.close()
    finally:
        stop_process(server)
