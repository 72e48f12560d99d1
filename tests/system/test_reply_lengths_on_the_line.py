"""Replies whose length is parsed field by field (2BH/0EH device identification, 18H FIFO) end
at their last byte on a real serial path, not on silence: the whole gateway, a pty cable, and at
its far end a device that answers them."""

from __future__ import annotations

import os
import select
import threading
import tty
from collections.abc import Iterator

import pytest

from gateway.modbus.crc import crc_ok
from gateway.modbus.rtu import build_frame
from tests.support import TcpClient, gateway_config, pty_cable, running_gateway

ADDRESS = 7
NOISE = bytes.fromhex("00 FF 55 AA")
"""What the line carries right after the reply. Ended on silence, the reply would take it in and
fail its CRC; ended by length, it is left for the line to throw away."""
IDENTITY = bytes.fromhex("2B 0E 01 01 00 00 03") + b"".join(
    bytes((object_id, len(value))) + value
    for object_id, value in enumerate((b"INVT", b"Goodrive350", b"V1.40"))
)
FIFO = bytes.fromhex("18 00 06 00 02 01 B8 12 84")
ANSWERS = {0x2B: IDENTITY, 0x18: FIFO}


class IdentifyingDevice:
    """Answers 2BH/0EH and 18H at `ADDRESS`, each reply followed at once by `NOISE`."""

    def __init__(self, path: str) -> None:
        self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
        tty.setraw(self.fd)
        self.requests: list[bytes] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="identifying-device", daemon=True)

    def __enter__(self) -> IdentifyingDevice:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(2)
        os.close(self.fd)

    def _serve(self) -> None:
        frame = b""
        while not self._stop.is_set():
            ready, _, _ = select.select([self.fd], [], [], 0.05)
            if not ready:
                continue
            frame += os.read(self.fd, 256)
            if len(frame) < 4 or not crc_ok(frame):
                continue  # the rest of the request is still on its way
            self.requests.append(frame)
            if frame[0] == ADDRESS and frame[1] in ANSWERS:
                os.write(self.fd, build_frame(ADDRESS, ANSWERS[frame[1]]) + NOISE)
            frame = b""


@pytest.fixture
def line() -> Iterator[tuple[str, IdentifyingDevice]]:
    with pty_cable() as (gateway_end, device_end), IdentifyingDevice(device_end) as device:
        yield gateway_end, device


async def test_device_identification_and_fifo_replies_end_by_their_length(
    line: tuple[str, IdentifyingDevice],
) -> None:
    port, device = line
    # Silence inside a reply has to last 5 s to end it: a reply that waited for silence would
    # miss the client's 5 s, besides taking the noise in.
    config = gateway_config(
        port,
        [{"name": "meter", "address": ADDRESS, "model": "generic"}],
        parity="N",
        timeout_ms=1000,
        char_timeout_ms=5000,
        retries=0,
    )
    async with running_gateway(config) as app:
        client = await TcpClient.connect(app.tcp.port)
        try:
            assert await client.request(ADDRESS, bytes.fromhex("2B 0E 01 00")) == IDENTITY
            assert await client.request(ADDRESS, bytes.fromhex("18 04 DE")) == FIFO
            # The noise was the line's to drop: the next exchange is still in step.
            assert await client.request(ADDRESS, bytes.fromhex("2B 0E 01 00")) == IDENTITY
        finally:
            await client.close()
    assert [request[1] for request in device.requests] == [0x2B, 0x18, 0x2B]
