"""A real libmodbus RTU slave behind the gateway: it frames no 08H, so nothing may depend on it.

Built by the test from tests/peers/libmodbus/rtu_slave.c (Debian's libmodbus-dev and gcc, which
`.ci/test` installs), wired to the gateway through a pty pair made by socat, and stalled with
SIGSTOP while a SCADA client reads in a loop: the gateway must bring it back in step with what
it does frame, and never hand a client a reply that was not the answer.
"""

from __future__ import annotations

import asyncio
import os
import shutil
import signal
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.support import TcpClient, gateway_config, read_pdu, running_gateway

SOURCE = Path(__file__).parents[1] / "peers" / "libmodbus" / "rtu_slave.c"
UNIT = 1
EXPECTED = bytes.fromhex("03 04 10 00 10 01")  # holding registers 0 and 1: 1000H, 1001H


@pytest.fixture(scope="module")
def rtu_slave_program(tmp_path_factory: pytest.TempPathFactory) -> Path:
    program = tmp_path_factory.mktemp("libmodbus") / "rtu_slave"
    subprocess.run(
        ["gcc", "-O2", "-o", str(program), str(SOURCE), "-lmodbus"],
        check=True,
        capture_output=True,
    )
    return program


@pytest.fixture
def libmodbus_slave(rtu_slave_program: Path, tmp_path: Path) -> Iterator[tuple[str, int]]:
    """(the gateway's end of the line, the slave's pid)."""
    gateway_end, slave_end = tmp_path / "gateway", tmp_path / "slave"
    socat = subprocess.Popen(
        [
            shutil.which("socat") or "socat",
            f"pty,raw,echo=0,link={gateway_end}",
            f"pty,raw,echo=0,link={slave_end}",
        ]
    )
    try:
        deadline = time.monotonic() + 5
        while not (gateway_end.exists() and slave_end.exists()):
            assert time.monotonic() < deadline, "socat made no pty pair"
            time.sleep(0.02)
        slave = subprocess.Popen(
            [str(rtu_slave_program), str(slave_end), str(UNIT)], stdout=subprocess.PIPE
        )
        assert slave.stdout is not None
        assert slave.stdout.readline().strip() == b"ready"
        try:
            yield str(gateway_end), slave.pid
        finally:
            os.kill(slave.pid, signal.SIGCONT)
            slave.kill()
            slave.wait()
            slave.stdout.close()
    finally:
        socat.kill()
        socat.wait()


async def read_until(port: int, until: float) -> list[tuple[float, bytes]]:
    client = await TcpClient.connect(port)
    replies = []
    try:
        while (asked := time.monotonic()) < until:
            replies.append((asked, await client.request(UNIT, read_pdu(0, 2), 10)))
            await asyncio.sleep(0.01)
    finally:
        await client.close()
    return replies


@pytest.mark.parametrize("stall_s", [0.4, 3.0])
async def test_a_libmodbus_slave_stalled_is_back_within_a_second_and_never_out_of_step(
    libmodbus_slave: tuple[str, int], stall_s: float
) -> None:
    path, pid = libmodbus_slave
    config = gateway_config(
        path,
        [{"name": "io", "address": UNIT, "model": "generic"}],
        baudrate=19200,
        timeout_ms=300,
        retries=2,
    )
    async with running_gateway(config) as app:
        reading = asyncio.create_task(read_until(app.tcp.port, time.monotonic() + 3 + stall_s + 3))
        await asyncio.sleep(1.0)
        stopped = time.monotonic()
        os.kill(pid, signal.SIGSTOP)
        await asyncio.sleep(stall_s)
        os.kill(pid, signal.SIGCONT)
        carried_on = time.monotonic()
        replies = await reading
        timeouts = app.buses["line1"].drive_stats[UNIT].timeouts
    wrong = [reply.hex(" ") for _, reply in replies if reply not in (EXPECTED, b"\x83\x0b")]
    assert not wrong, wrong
    # Asked before the stop: one in flight as it came may fail (an error, never a wrong value).
    before = [reply for asked, reply in replies if asked < stopped - 0.5]
    assert before
    assert set(before) == {EXPECTED}
    after = [(asked, reply) for asked, reply in replies if asked >= carried_on]
    first_good = next(asked for asked, reply in after if reply == EXPECTED)
    assert first_good - carried_on < 1.0, f"back {first_good - carried_on:.2f} s after"
    settled = [reply for asked, reply in after if asked >= carried_on + 1.0]
    assert settled
    assert set(settled) == {EXPECTED}
    assert timeouts > 0  # the stall was felt
