"""The one case where a drive's reply is not passed through byte-exact (README, "Modbus-TCP
behaviour"): a well-framed reply whose byte count or echo contradicts the request.

The drive here is a pty whose other end answers every request with such a reply: right CRC,
address and function code, wrong content. RTU has no transaction id, so the gateway takes it for
a late answer to something else: set aside (never the answer), counted as `mismatch`, the drive
resynchronised before it is asked again, and the client answered 0BH.
"""

from __future__ import annotations

import contextlib
import os
import select
import struct
import threading
from collections.abc import Callable, Iterator

from gateway.modbus.rtu import build_frame
from tests.support import TcpClient, gateway_config, read_pdu, running_gateway, write_pdu

REQUEST_BYTES = 8  # 03H and 06H requests: address, function, 2 + 2 bytes, CRC


@contextlib.contextmanager
def contradicting_drive(answer: Callable[[bytes], bytes]) -> Iterator[tuple[str, list[bytes]]]:
    """A drive on a pty that answers each request (address + PDU) with `answer(request)`, a
    frame with a good CRC; yields the device path and the requests it got."""
    master, slave = os.openpty()
    requests: list[bytes] = []
    stop_r, stop_w = os.pipe()

    def serve() -> None:
        pending = b""
        while True:
            ready, _, _ = select.select([master, stop_r], [], [])
            if stop_r in ready:
                return
            pending += os.read(master, 256)
            while len(pending) >= REQUEST_BYTES:
                request, pending = pending[:REQUEST_BYTES], pending[REQUEST_BYTES:]
                requests.append(request)
                os.write(master, build_frame(request[0], answer(request[1:-2])))

    thread = threading.Thread(target=serve, name="contradicting-drive", daemon=True)
    thread.start()
    try:
        yield os.ttyname(slave), requests
    finally:
        os.write(stop_w, b"x")
        thread.join(2)
        for fd in (master, slave, stop_r, stop_w):
            os.close(fd)


def one_register_too_few(pdu: bytes) -> bytes:
    """A read reply with the values of one register less than asked for; a write echo with
    another value."""
    if pdu[0] == 0x03:
        count: int = struct.unpack(">H", pdu[3:5])[0] - 1
        return bytes((0x03, 2 * count)) + b"\x00\x07" * count
    return pdu[:3] + struct.pack(">H", (struct.unpack(">H", pdu[3:5])[0] + 1) & 0xFFFF)


async def test_a_reply_that_contradicts_the_request_is_answered_0bh_not_forwarded() -> None:
    with contradicting_drive(one_register_too_few) as (path, requests):
        config = gateway_config(path, [{"name": "pump1", "address": 1}], retries=2, timeout_ms=100)
        async with running_gateway(config) as app:
            client = await TcpClient.connect(app.tcp.port)
            # Two registers asked, one sent back: the client gets 0BH, not the drive's bytes.
            assert await client.request(1, read_pdu(0x2100, 2)) == bytes.fromhex("83 0B")
            # A write whose echo carries another value: the same.
            assert await client.request(1, write_pdu(0x2001, 2500)) == bytes.fromhex("86 0B")
            await client.close()
            bus = app.buses["line1"]
            # Each request's contradicting reply, and each marker's after it, is counted; the
            # drive is never trusted again without a marker answered in step (it never is).
            assert bus.stats.bad_replies["mismatch"] >= 2
            assert bus.stats.drives[1].resyncs >= 2
            assert len(requests) == 6  # 3 attempts each: a marker, then a marker again
