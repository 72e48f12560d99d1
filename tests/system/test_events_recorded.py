"""What else becomes an event in the store: SCADA's writes, tallied per client, unit id and
minute (through a SIGKILL too); a bus's port lost and back."""

from __future__ import annotations

import asyncio
import contextlib
import json
import signal
import sqlite3
import struct
import time
from collections import Counter
from pathlib import Path
from typing import Any

from gateway.instruments.simulator import SimulatedLine
from gateway.profile.invt import STATE_WORD_1
from gateway.store import EventType
from tests.support import (
    TcpClient,
    free_port,
    gateway_config,
    read_pdu,
    running_gateway,
    write_pdu,
)
from tests.support.mqtt_setup import simulated_line
from tests.support.processes import gateway_process

DRIVES = [{"name": "pump1", "address": 1}, {"name": "fan2", "address": 2}]
FREQUENCY_SETPOINT = 0x2001


async def test_scada_writes_are_one_event_per_client_unit_and_minute(
    line_link: tuple[SimulatedLine, Path],
) -> None:
    _line, link = line_link
    config = gateway_config(str(link), DRIVES)
    async with running_gateway(config) as app:
        client = await TcpClient.connect(app.tcp.port)
        try:
            for value in range(1000, 1020):  # a set-point every few ms: 20 writes
                assert await client.request(1, write_pdu(FREQUENCY_SETPOINT, value)) is not None
            refused = await client.request(1, struct.pack(">BHH", 6, 0x3000, 1))  # read-only
            assert refused[0] == 0x86
            await client.request(2, write_pdu(FREQUENCY_SETPOINT, 500))
            await client.read(1, STATE_WORD_1)  # a read is no write: not counted
        finally:
            await client.close()
        app.writes.flush(until_minute=None)  # what the end of the minute (or a stop) does
        await app.events.flush()
        events = await app.events.recent_events(10)
    assert {e.type for e in events} == {EventType.MODBUS_WRITES}
    pump = [e.data for e in events if e.data["drive"] == "pump1"]
    fan = [e.data for e in events if e.data["drive"] == "fan2"]
    # One event per minute: two only if the test ran across a minute's end.
    assert 1 <= len(pump) <= 2
    assert sum(d["writes"] for d in pump) == 21
    assert sum(d["refused"] for d in pump) == 1
    assert {r for d in pump for r in d["registers"]} == {"2001H", "3000H"}
    for data in pump:
        assert data["client"] == "127.0.0.1"
        assert data["unit_id"] == 1
        assert data["functions"] == ["06"]
        assert data["from"] <= data["to"]
    assert [d["writes"] for d in fan] == [1]


def writes_in_store(store: Path) -> Counter[str]:
    """SCADA writes per client, as an operator's sqlite3 reads them from the store's events."""
    with contextlib.closing(sqlite3.connect(f"file:{store}?mode=ro", uri=True)) as db:
        rows = db.execute("SELECT data FROM events WHERE type = 'modbus_writes'").fetchall()
    writes: Counter[str] = Counter()
    for (data,) in rows:
        event = json.loads(data)
        writes[event["client"]] += event["writes"]
    return writes


def file_config(line_path: str, tcp_port: int, store: Path) -> dict[str, Any]:
    return {
        "gateway_id": "audit",
        "modbus_tcp": {"host": "127.0.0.1", "port": tcp_port},
        "buses": [{"name": "line1", "port": line_path, "baudrate": 115200, "parity": "E"}],
        "drives": [{"bus": "line1", "name": "pump1", "address": 1, "model": "gd350"}],
        "storage": {"path": str(store)},
    }


async def test_scada_writes_of_the_minute_survive_a_sigkill(tmp_path: Path) -> None:
    store = tmp_path / "events.db"
    clients = [f"127.0.0.{n}" for n in range(2, 7)]
    if time.time() % 60 > 45:
        await asyncio.sleep(60 - time.time() % 60)  # the writes and the kill in one minute
    with simulated_line((1,)) as line:
        config = file_config(line.path, free_port(), store)
        with gateway_process(config, tmp_path) as gateway:
            gateway.wait_ready()
            port = config["modbus_tcp"]["port"]
            for source in clients:  # two set-points from each of five SCADA hosts
                client = await TcpClient.connect(port, source=source)
                try:
                    for value in (1000, 1500):
                        reply = await client.request(1, write_pdu(FREQUENCY_SETPOINT, value))
                        assert reply == write_pdu(FREQUENCY_SETPOINT, value)
                finally:
                    await client.close()
            await asyncio.sleep(1.0)  # what is tallied is in the store within a second
            gateway.signal(signal.SIGKILL)  # in the same minute: no tally was complete
            assert gateway.wait(5) == -signal.SIGKILL
        with gateway_process(config, tmp_path) as gateway:
            gateway.wait_ready()
            writes = writes_in_store(store)
    assert writes == dict.fromkeys(clients, 2)


async def test_a_port_lost_and_back_are_events(line_link: tuple[SimulatedLine, Path]) -> None:
    line, link = line_link
    config = gateway_config(str(link), DRIVES, timeout_ms=50, retries=0)
    async with running_gateway(config) as app:
        client = await TcpClient.connect(app.tcp.port)
        try:
            line.unplug()
            assert await client.request(1, read_pdu(STATE_WORD_1)) == bytes.fromhex("83 0B")
            line.replug()
            for _ in range(100):
                if (await client.request(1, read_pdu(STATE_WORD_1)))[0] == 3:
                    break
                await asyncio.sleep(0.1)  # the bus reopens with backoff
        finally:
            await client.close()
        await app.events.flush()
        events = await app.events.recent_events(10)
    kinds = [e.type for e in reversed(events) if e.type in ("port_lost", "port_back")]
    assert kinds == ["port_lost", "port_back"]
    lost = next(e for e in events if e.type == "port_lost")
    assert lost.data["bus"] == "line1"
    assert lost.data["port"] == str(link)
    assert lost.data["reason"]
