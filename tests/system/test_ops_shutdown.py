"""Graceful shutdown of a real `invt-gateway run` process: the signal arrives while one request is
on the wire and more are queued behind it. The one on the wire finishes and is answered; every
queued one is answered 0x0B at once; the process exits 0 within 2 s.

The line runs at 1200 baud with real wire timing, so a 16-word read holds it for about 0.4 s:
long enough to be sure where each request is when the signal comes.
"""

from __future__ import annotations

import asyncio
import signal
import struct
import time
from pathlib import Path

import pytest

from gateway.instruments.simulator import SimulatedLine
from tests.support import (
    Swallower,
    TcpClient,
    eventually,
    free_port,
    gateway_config,
    running_gateway,
)
from tests.support.processes import gateway_process

QUEUED = 6
WORDS = 16
EXIT_WITHIN_S = 2.0


def read_block(start: int) -> bytes:
    return struct.pack(">BHH", 3, start, WORDS)


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
async def test_signal_answers_queued_requests_0x0b_and_exits_0_within_2_s(
    tmp_path: Path, signum: signal.Signals
) -> None:
    tcp_port = free_port()
    with SimulatedLine(addresses=[1], baudrate=1200, parity="E", wire_time=True) as line:
        config = {
            "gateway_id": "shutdown",
            "modbus_tcp": {"host": "127.0.0.1", "port": tcp_port},
            "buses": [{"name": "line1", "port": line.path, "baudrate": 1200, "timeout_ms": 1000}],
            "drives": [{"name": "pump1", "bus": "line1", "address": 1}],
        }
        with gateway_process(config, tmp_path) as gateway:
            await asyncio.to_thread(gateway.wait_ready)
            client = await TcpClient.connect(tcp_port)
            # Different blocks, so no two reads are coalesced: one on the wire, the rest queued.
            on_wire = client.send(1, read_block(0x3000))
            queued = [client.send(1, read_block(0x3000 + n)) for n in range(1, QUEUED + 1)]
            # Until the first read is on the wire (it takes ~0.4 s).
            await eventually(lambda: line.stats["requests"], what="the first read on the wire")

            signalled = time.monotonic()
            gateway.signal(signum)
            answers = {}
            for _ in range(QUEUED + 1):
                reply = await client.receive(within_s=EXIT_WITHIN_S)
                answers[reply.transaction_id] = (reply.pdu, time.monotonic() - signalled)
            code = await asyncio.to_thread(gateway.wait, EXIT_WITHIN_S)
            exited_after = time.monotonic() - signalled
            await client.close()

    assert code == 0, gateway.log.text
    assert exited_after < EXIT_WITHIN_S, f"exit took {exited_after:.2f} s"
    pdu, wire_done = answers[on_wire]
    assert pdu[:2] == bytes((3, 2 * WORDS)), f"the transaction on the wire: {pdu.hex(' ')}"
    for transaction in queued:
        pdu, after = answers[transaction]
        assert pdu == bytes.fromhex("83 0b"), pdu.hex(" ")
        # Answered at once, before the transaction on the wire has finished.
        assert after < wire_done, "queued requests are answered at once, not after the wire"
    assert f"{signum.name} received: shutting down" in gateway.log.text


async def test_work_that_swallows_its_cancellations_does_not_hold_up_the_stop(
    line: SimulatedLine,
) -> None:
    """As the MQTT publisher did on Python 3.11 when a cancellation landed on aiomqtt's
    `wait_for` as its PUBACK came: the service stopped its feature, the work went on, and the
    service waited for it for ever. Now a last sweep ends it, and the service stops."""
    stubborn = Swallower(times=8)  # past the 0.5 s a feature's own stop is given
    async with running_gateway(gateway_config(line.path, [{"name": "pump1", "address": 1}])) as app:
        app.tasks.start("stubborn", stubborn.run())
        started = time.monotonic()
    # running_gateway's exit asserts the gateway stopped within 5 s
    assert stubborn.ended
    assert time.monotonic() - started < EXIT_WITHIN_S
