"""The OPC UA endpoint under malformed messages: a few hundred of `invt-gateway stress
--opcua-fuzz`'s (random bytes, bad Hellos, oversized and cut-short messages, garbage on an open
channel) to the gateway as systemd runs it, which answers them without a traceback and goes on
serving Modbus-TCP and OPC UA."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from gateway.instruments.simulator import SimulatedLine
from gateway.instruments.stress.opcua_fuzz import OpcUaFuzzer
from tests.support import TcpClient
from tests.support.opcua import configuration_file
from tests.support.processes import gateway_process

pytestmark = pytest.mark.line(addresses=(1, 2))

MESSAGES = 300


async def test_malformed_messages_leave_no_traceback_and_the_gateway_serving(
    line: SimulatedLine, tmp_path: Path
) -> None:
    config = configuration_file(line, security=["None", "Basic256Sha256_SignAndEncrypt"])
    with gateway_process(config, tmp_path) as gateway:
        await asyncio.to_thread(gateway.wait_ready)
        fuzzer = OpcUaFuzzer("127.0.0.1", config["opcua"]["port"], seed=47)
        stats = await fuzzer.run(MESSAGES)
        assert stats.messages == MESSAGES
        assert stats.refused == 0
        modbus = await TcpClient.connect(config["modbus_tcp"]["port"])
        assert await modbus.read(1, 0x2100) != []  # state word 1 of pump1, from the line
        modbus.writer.close()
        again = await OpcUaFuzzer("127.0.0.1", config["opcua"]["port"], 0).hello_answer()
        assert again == "ACK"  # a well-formed Hello still gets its Acknowledge
    assert "OPC UA: a client's message refused: " in gateway.log.text  # one line, the client's
    for bad in ("Traceback", " ERROR ", " CRITICAL "):
        assert bad not in gateway.log.text, gateway.log.text[-5000:]
