"""Test helpers that talk to real things: TCP sockets, pty serial lines, subprocesses."""

from __future__ import annotations

import asyncio
import contextlib
import inspect
import os
import re
import select
import socket
import struct
import threading
import time
import tty
from collections.abc import AsyncIterator, Callable, Iterator
from dataclasses import dataclass
from typing import Any, TypeAlias, TypeVar

from gateway.app import Application
from gateway.bus import Bus
from gateway.config import BusConfig, GatewayConfig
from gateway.instruments.bench.processes import (
    free_port as free_port,  # the tests' one way to a free port
)
from gateway.settings import bus_settings, runtime_settings

T = TypeVar("T")

RecordProperty: TypeAlias = Callable[[str, object], None]
"""The type of pytest's `record_property` fixture (pytest exports no name for it): records a
key and value as a property of the test in the JUnit XML report."""


def present(part: T | None) -> T:
    """An optional part of the application that the test configured (`app.mqtt`,
    `app.console`: None when their section is absent)."""
    assert part is not None, "the test's configuration has no such part"
    return part


async def eventually(
    check: Callable[[], object], within_s: float = 5.0, what: str = "", every_s: float = 0.005
) -> None:
    """Wait until `check()` (or what it returns, awaited) is true, asking every `every_s`: for a
    state the code under test exposes no event for (a counter, a flag, a drive's state word read
    over Modbus). Fails after `within_s`."""
    deadline = time.monotonic() + within_s
    while True:
        result = check()
        if inspect.isawaitable(result):
            result = await result
        if result:
            return
        if time.monotonic() > deadline:
            raise AssertionError(f"not reached within {within_s} s: {what or check}")
        await asyncio.sleep(every_s)


def scan_rows(output: str) -> dict[int, list[str]]:
    """`invt-gateway scan`'s table, by address: the cells, split on the table's column gaps."""
    rows = {}
    for line in output.splitlines():
        cells = re.split(r"\s{2,}", line.strip())
        if cells and cells[0].isdigit():
            rows[int(cells[0])] = cells[1:]
    return rows


def gateway_config(port: str, drives: list[dict[str, Any]], **bus: Any) -> GatewayConfig:
    """A configuration with one bus on `port` and Modbus-TCP on a free loopback port."""
    bus_config = {
        "name": "line1",
        "port": port,
        "baudrate": 115200,
        "parity": "E",
        "timeout_ms": 200,
        "retries": 1,
        **bus,
    }
    return GatewayConfig.model_validate(
        {
            "modbus_tcp": {"host": "127.0.0.1", "port": 0},
            "buses": [bus_config],
            "drives": [{"bus": "line1", **d} for d in drives],
        }
    )


@contextlib.asynccontextmanager
async def running_gateway(config: GatewayConfig) -> AsyncIterator[Application]:
    """The whole application in this event loop, listening on a real TCP port."""
    async with running_application(Application(runtime_settings(config))) as app:
        yield app


@contextlib.asynccontextmanager
async def running_application(app: Application) -> AsyncIterator[Application]:
    """`running_gateway` for an application a test has built (and may have added to)."""
    stop = asyncio.Event()
    ready = asyncio.Event()
    task = asyncio.create_task(app.run(stop, ready.set))
    ready_wait = asyncio.create_task(ready.wait())
    await asyncio.wait({task, ready_wait}, return_when=asyncio.FIRST_COMPLETED, timeout=10)
    if task.done():
        ready_wait.cancel()
        task.result()  # raises the start-up error
    try:
        yield app
    finally:
        stop.set()
        # Not wait_for: on Python 3.11 it waits, after its timeout, for the task it cancelled.
        done, _ = await asyncio.wait({task}, timeout=5)
        assert done, "the gateway did not stop within 5 s"
        task.result()


@contextlib.asynccontextmanager
async def running_bus(port: str, **bus: Any) -> AsyncIterator[Bus]:
    """One bus on `port` (a simulated line's path), serving in this event loop, without the rest
    of the gateway: for the tests of the bus and of what sits right on it (routing)."""
    config = BusConfig.model_validate({"name": "line1", "port": port, "baudrate": 115200, **bus})
    bus_ = Bus(bus_settings(config))
    running = asyncio.create_task(bus_.run())
    try:
        assert await bus_.wait_open(5.0), f"{port} did not open"
        yield bus_
    finally:
        bus_.close()
        await asyncio.wait_for(running, 5)


@dataclass
class Reply:
    transaction_id: int
    unit_id: int
    pdu: bytes


class TcpClient:
    """A minimal Modbus-TCP client over a real socket, for byte-exact checks and pipelining."""

    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.reader = reader
        self.writer = writer
        self._next_tid = 1

    @classmethod
    async def connect(
        cls, port: int, host: str = "127.0.0.1", source: str | None = None
    ) -> TcpClient:
        """`source`: the address to connect from (another loopback address: another client)."""
        local = None if source is None else (source, 0)
        reader, writer = await asyncio.open_connection(host, port, local_addr=local)
        return cls(reader, writer)

    def send(self, unit_id: int, pdu: bytes, transaction_id: int | None = None) -> int:
        tid = self._next_tid if transaction_id is None else transaction_id
        self._next_tid = (tid + 1) & 0xFFFF
        self.writer.write(struct.pack(">HHHB", tid, 0, len(pdu) + 1, unit_id) + pdu)
        return tid

    async def receive(self, within_s: float = 5.0) -> Reply:
        header = await asyncio.wait_for(self.reader.readexactly(7), within_s)
        tid, protocol, length, unit = struct.unpack(">HHHB", header)
        assert protocol == 0
        pdu = await asyncio.wait_for(self.reader.readexactly(length - 1), within_s)
        return Reply(tid, unit, pdu)

    async def request(self, unit_id: int, pdu: bytes, within_s: float = 5.0) -> bytes:
        tid = self.send(unit_id, pdu)
        reply = await self.receive(within_s)
        assert reply.transaction_id == tid
        assert reply.unit_id == unit_id
        return reply.pdu

    async def read(self, unit_id: int, register: int, count: int = 1) -> list[int]:
        pdu = await self.request(unit_id, struct.pack(">BHH", 3, register, count))
        assert pdu[0] == 3, f"exception {pdu.hex(' ')}"
        return list(struct.unpack(f">{count}H", pdu[2:]))

    async def close(self) -> None:
        self.writer.close()
        with contextlib.suppress(Exception):
            await self.writer.wait_closed()


def read_pdu(register: int, count: int = 1) -> bytes:
    return struct.pack(">BHH", 3, register, count)


def write_pdu(register: int, value: int) -> bytes:
    return struct.pack(">BHH", 6, register, value)


def write_many(register: int, *values: int) -> bytes:
    """10H: `values` written from `register` on."""
    count = len(values)
    return struct.pack(f">BHHB{count}H", 0x10, register, count, 2 * count, *values)


@contextlib.contextmanager
def pty_cable() -> Iterator[tuple[str, str]]:
    """A virtual null-modem cable: two pty device paths, whatever is written to one comes out of
    the other. Lets two programs that each want a serial device path (the gateway and pymodbus's
    RTU server) talk over a real serial path."""
    master_a, slave_a = os.openpty()
    master_b, slave_b = os.openpty()
    for fd in (slave_a, slave_b):
        tty.setraw(fd)
    stop_r, stop_w = os.pipe()
    pairs = {master_a: master_b, master_b: master_a}

    def pump() -> None:
        while True:
            ready, _, _ = select.select([master_a, master_b, stop_r], [], [])
            if stop_r in ready:
                return
            for fd in ready:
                try:
                    data = os.read(fd, 4096)
                except OSError:
                    continue
                os.write(pairs[fd], data)

    thread = threading.Thread(target=pump, name="pty-cable", daemon=True)
    thread.start()
    try:
        yield os.ttyname(slave_a), os.ttyname(slave_b)
    finally:
        os.write(stop_w, b"x")
        thread.join(2)
        for fd in (master_a, master_b, slave_a, slave_b, stop_r, stop_w):
            os.close(fd)


class Swallower:
    """Work that ignores the first cancellation it gets and goes on, as a task awaiting
    `asyncio.wait_for` does on Python 3.11 when the cancellation lands as the awaited future
    completes (CPython gh-86296): what left the bridge's publisher running after a stop."""

    def __init__(self, times: int = 1) -> None:
        self.times = times
        self.swallowed = 0
        self.ended = False

    async def run(self) -> None:
        try:
            while True:
                try:
                    await asyncio.sleep(3600)
                except asyncio.CancelledError:
                    if self.swallowed == self.times:
                        raise
                    self.swallowed += 1
        finally:
            self.ended = True


def read_state_word(port: int, unit_id: int) -> bytes:
    """State word 1 of `unit_id` read over a plain blocking socket, as a probe from another
    process would: the reply's PDU."""
    with socket.create_connection(("127.0.0.1", port), timeout=5) as connection:
        connection.sendall(struct.pack(">HHHBBHH", 7, 0, 6, unit_id, 3, 0x2100, 1))
        return connection.recv(256)[7:]


def receive_exactly(sock: socket.socket, count: int) -> bytes:
    """`count` bytes from a blocking socket (ConnectionResetError if the peer closes first)."""
    data = b""
    while len(data) < count:
        chunk = sock.recv(count - len(data))
        if not chunk:
            raise ConnectionResetError("the peer closed the connection")
        data += chunk
    return data


def protected_config(line_path: str, **tcp: Any) -> GatewayConfig:
    """Two drives (pump1 at 1, fan2 at 2) and Modbus-TCP on a free loopback port with the
    server's options `tcp` (its limits and protections)."""
    return GatewayConfig.model_validate(
        {
            "modbus_tcp": {"host": "127.0.0.1", "port": 0, **tcp},
            "buses": [{"name": "line1", "port": line_path, "baudrate": 115200}],
            "drives": [
                {"name": "pump1", "bus": "line1", "address": 1},
                {"name": "fan2", "bus": "line1", "address": 2},
            ],
        }
    )
