"""Interoperability with peers nobody here wrote: pymodbus's RTU server as the drive, pymodbus's
TCP client and mbpoll as the SCADA."""

from __future__ import annotations

import asyncio
import shutil
from collections.abc import AsyncIterator, Iterator
from pathlib import Path

import pytest
from pymodbus.client import AsyncModbusTcpClient

from gateway.app import Application
from gateway.instruments.simulator import SimulatedLine
from tests.support import TcpClient, eventually, gateway_config, running_gateway
from tests.support.processes import pymodbus_peer

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def pymodbus_slave() -> Iterator[str]:
    """pymodbus's RTU server answering as units 1 and 2 at the far end of a pty cable; yields the
    device path the gateway opens. N81: a Linux pty refuses pyserial's re-configuration once a
    parity is set, which pymodbus's serial transport does after opening."""
    with pymodbus_peer("pymodbus_rtu_slave", "19200", "1", "2") as gateway_end:
        yield gateway_end


async def test_gateway_as_master_of_pymodbus_rtu_server(pymodbus_slave: str) -> None:
    drives = [
        {"name": "peer1", "address": 1, "model": "generic"},
        {"name": "peer2", "address": 2, "model": "generic", "unit_id": 12},
    ]
    config = gateway_config(pymodbus_slave, drives, baudrate=19200, parity="N", timeout_ms=500)
    async with running_gateway(config) as app:
        client = await TcpClient.connect(app.tcp.port)
        assert await client.read(1, 0, 3) == [1010, 1011, 1012]
        assert await client.read(12, 0, 2) == [1020, 1021]  # unit id 12 remapped to address 2
        assert await client.request(1, bytes.fromhex("04 00 00 00 02")) == bytes.fromhex(
            "04 04 13 88 13 89"
        )
        assert await client.request(1, bytes.fromhex("01 00 00 00 08")) == bytes.fromhex("01 01 AA")
        assert await client.request(1, bytes.fromhex("06 00 05 00 2A")) == bytes.fromhex(
            "06 00 05 00 2A"
        )
        assert await client.request(1, bytes.fromhex("10 00 00 00 02 04 00 07 00 08")) == (
            bytes.fromhex("10 00 00 00 02")
        )
        assert await client.read(1, 0, 6) == [7, 8, 1012, 1013, 1014, 42]
        # Its exception for an address it doesn't have passes through byte-exact.
        assert await client.request(1, bytes.fromhex("03 00 C8 00 01")) == bytes.fromhex("83 02")
        assert await client.request(1, bytes.fromhex("08 00 00 12 AB")) == bytes.fromhex(
            "08 00 00 12 AB"
        )
        # 2BH/0EH ends at the length its objects add up to, as another implementation wrote it.
        reply = await client.request(1, bytes.fromhex("2B 0E 01 00"))
        assert reply[:3] == bytes.fromhex("2B 0E 01")
        await client.close()


@pytest.fixture
async def gateway(line: SimulatedLine) -> AsyncIterator[Application]:
    drives = [{"name": "pump1", "address": 1}, {"name": "fan2", "address": 2}]
    async with running_gateway(gateway_config(line.path, drives, timeout_ms=50)) as app:
        yield app


async def test_pymodbus_client_as_scada(gateway: Application, line: SimulatedLine) -> None:
    client = AsyncModbusTcpClient("127.0.0.1", port=gateway.tcp.port, timeout=5, retries=0)
    await client.connect()
    try:
        result = await client.read_holding_registers(0x2100, count=1, device_id=1)
        assert not result.isError()
        assert result.registers == [3]  # stopped
        result = await client.write_registers(0x2000, [1, 2500], device_id=2)
        assert not result.isError()
        result = await client.read_holding_registers(0x2001, count=1, device_id=2)
        assert result.registers == [2500]

        async def running_forward() -> bool:
            result = await client.read_holding_registers(0x2100, count=1, device_id=2)
            return bool(result.registers == [1])

        await eventually(running_forward, within_s=2.0, every_s=0.02)
        # INVT's exception 04H for P00.01 = 3 reaches pymodbus intact.
        result = await client.write_register(0x0001, 3, device_id=1)
        assert result.isError()
        assert result.exception_code == 4
        # Unknown unit id: 0x0A from the gateway.
        result = await client.read_holding_registers(0x2100, count=1, device_id=77)
        assert result.exception_code == 0x0A
        line.set_dead(1, True)
        result = await client.read_holding_registers(0x2100, count=1, device_id=1)
        assert result.exception_code == 0x0B
    finally:
        client.close()


@pytest.mark.skipif(shutil.which("mbpoll") is None, reason="mbpoll is installed by .ci/test")
async def test_mbpoll_as_scada(gateway: Application) -> None:
    port = str(gateway.tcp.port)

    async def mbpoll(*args: str) -> str:
        process = await asyncio.create_subprocess_exec(
            "mbpoll",
            "-m",
            "tcp",
            "-p",
            port,
            "-0",
            "-1",
            *args,
            stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.STDOUT,
        )
        out, _ = await asyncio.wait_for(process.communicate(), 20)
        return out.decode()

    # State word 1 (2100H = 8448) of drive 1: 3, stopped.
    assert "[8448]: \t3" in await mbpoll("-a", "1", "-r", "8448", "127.0.0.1")
    # Write P00.05 (0005H) = 1234 on drive 2, read it back.
    assert "Written 1 references" in await mbpoll("-a", "2", "-r", "5", "127.0.0.1", "1234")
    assert "[5]: \t1234" in await mbpoll("-a", "2", "-r", "5", "127.0.0.1")
