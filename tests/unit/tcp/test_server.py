"""The Modbus-TCP front door on its own: a real listening socket, and a handler of a few lines
in place of the routing room. What a SCADA engineer checks on the wire: each answer carries its
own transaction id and goes out when ready (not in request order), every error becomes one
exception PDU and the connection stays, broadcasts are echoed or not as configured, and a
client outside the allowed networks never gets a connection."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator

import pytest

from gateway.errors import DriveOffline, GatewayTargetFailed
from gateway.tcp.server import ModbusTcpServer, TcpSettings
from tests.support import TcpClient, read_pdu, write_pdu

STATE_WORD_1 = 0x2100
STOPPED = bytes.fromhex("03 02 00 03")


class Drives:
    """The tiny request route: unit 1 answers at once, unit 2 when the test releases it, unit 3
    is offline, unit 4 has no path, unit 5 has a bug; unit 0 is a broadcast. It notes what it
    saw. Every request takes `execute` (`submit` starts none)."""

    def __init__(self) -> None:
        self.release_unit_2 = asyncio.Event()
        self.seen: list[tuple[int, bytes]] = []

    def submit(self, unit_id: int, pdu: bytes, client: str, waiter: object) -> bool:
        return False

    async def execute(self, unit_id: int, pdu: bytes, client: str) -> bytes | None:
        self.seen.append((unit_id, pdu))
        if unit_id == 0:
            return None
        if unit_id == 2:
            await self.release_unit_2.wait()
        if unit_id == 3:
            raise DriveOffline("drive 3 is offline")
        if unit_id == 4:
            raise GatewayTargetFailed("no answer")
        if unit_id == 5:
            raise RuntimeError("a bug in the gateway")
        return STOPPED


@contextlib.asynccontextmanager
async def front_door(drives: Drives, **settings: object) -> AsyncIterator[ModbusTcpServer]:
    settings_ = TcpSettings(host="127.0.0.1", port=0, **settings)  # type: ignore[arg-type]
    server = ModbusTcpServer(settings_, drives)
    await server.start()
    try:
        yield server
    finally:
        await server.stop()


async def test_answers_go_out_when_ready_each_with_its_own_transaction_id() -> None:
    drives = Drives()
    async with front_door(drives) as server:
        client = await TcpClient.connect(server.port)
        try:
            slow = client.send(2, read_pdu(STATE_WORD_1), transaction_id=0x1234)
            fast = client.send(1, read_pdu(STATE_WORD_1), transaction_id=0xBEEF)
            first = await client.receive()
            assert (first.transaction_id, first.unit_id, first.pdu) == (fast, 1, STOPPED)
            drives.release_unit_2.set()
            second = await client.receive()
            assert (second.transaction_id, second.unit_id, second.pdu) == (slow, 2, STOPPED)
        finally:
            await client.close()


@pytest.mark.parametrize(
    ("unit_id", "answer"),
    [
        (3, "83 0B"),  # offline drive: gateway target device failed to respond
        (4, "83 0B"),
        (5, "83 04"),  # a bug: server device failure, loudly logged
    ],
)
async def test_an_error_is_one_exception_pdu_and_the_connection_stays(
    unit_id: int, answer: str, caplog: pytest.LogCaptureFixture
) -> None:
    async with front_door(Drives()) as server:
        client = await TcpClient.connect(server.port)
        try:
            assert await client.request(unit_id, read_pdu(STATE_WORD_1)) == bytes.fromhex(answer)
            assert await client.request(1, read_pdu(STATE_WORD_1)) == STOPPED
        finally:
            await client.close()
    if unit_id == 5:
        assert "unexpected error" in caplog.text
    assert server.stats.exceptions == 1  # 04H for a bug counts like any exception answer


async def test_a_broadcast_is_echoed_unless_configured_not_to_be() -> None:
    request = write_pdu(0x2001, 2500)
    async with front_door(Drives()) as server:
        client = await TcpClient.connect(server.port)
        try:
            assert await client.request(0, request) == request
        finally:
            await client.close()
    drives = Drives()
    async with front_door(drives, broadcast_reply=False) as server:
        client = await TcpClient.connect(server.port)
        try:
            client.send(0, request)
            # No answer to the broadcast: the next answer on the socket is the read's.
            read = client.send(1, read_pdu(STATE_WORD_1))
            reply = await client.receive()
            assert (reply.transaction_id, reply.pdu) == (read, STOPPED)
            assert drives.seen[0] == (0, request)  # the broadcast did go to the line
        finally:
            await client.close()


async def test_read_only_refuses_writes_before_the_handler_sees_them() -> None:
    drives = Drives()
    async with front_door(drives, read_only=True) as server:
        client = await TcpClient.connect(server.port)
        try:
            assert await client.request(1, write_pdu(0x2000, 1)) == bytes.fromhex("86 01")
            assert await client.request(1, read_pdu(STATE_WORD_1)) == STOPPED
        finally:
            await client.close()
    assert drives.seen == [(1, read_pdu(STATE_WORD_1))]


async def test_a_client_outside_the_allowed_networks_is_closed_unanswered() -> None:
    async with front_door(Drives(), allowed_networks=("127.0.0.1/32",)) as server:
        reader, writer = await asyncio.open_connection(
            "127.0.0.1", server.port, local_addr=("127.0.0.2", 0)
        )
        try:
            writer.write(bytes.fromhex("00 01 00 00 00 06 01") + read_pdu(STATE_WORD_1))
            assert await asyncio.wait_for(reader.read(), 5) == b""  # closed, nothing said
        finally:
            writer.close()
        assert server.stats.refused == 1
        allowed = await TcpClient.connect(server.port)
        try:
            assert await allowed.request(1, read_pdu(STATE_WORD_1)) == STOPPED
        finally:
            await allowed.close()


async def test_a_frame_is_taken_whole_split_or_with_others_in_one_segment() -> None:
    """A frame that comes as one segment is read without the buffer; a frame cut in two, two
    frames in one segment and a segment with a bad header go the buffer's way: each request
    answered once, with its own transaction id, and the bad header closes the connection."""
    frame = bytes.fromhex("00 07 00 00 00 06 01") + read_pdu(STATE_WORD_1)
    answer = bytes.fromhex("00 07 00 00 00 05 01") + STOPPED
    drives = Drives()
    async with front_door(drives) as server:
        reader, writer = await asyncio.open_connection("127.0.0.1", server.port)
        try:
            writer.write(frame)  # whole
            assert await asyncio.wait_for(reader.readexactly(len(answer)), 5) == answer
            writer.write(frame[:4])  # cut in two
            await writer.drain()
            await asyncio.sleep(0.05)
            writer.write(frame[4:])
            assert await asyncio.wait_for(reader.readexactly(len(answer)), 5) == answer
            writer.write(frame + frame.replace(b"\x00\x07", b"\x00\x08", 1))  # two at once
            both = await asyncio.wait_for(reader.readexactly(2 * len(answer)), 5)
            assert both == answer + answer.replace(b"\x00\x07", b"\x00\x08", 1)
            assert len(drives.seen) == 4
            writer.write(frame[:2] + b"\x00\x01" + frame[4:])  # whole, but protocol id 1
            assert await asyncio.wait_for(reader.read(), 5) == b""  # closed, nothing said
        finally:
            writer.close()
    assert server.stats.malformed == 1
    assert server.stats.requests == 4
