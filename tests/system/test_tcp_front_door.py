"""Malformed requests are answered at the front door, from the function-code registry, without
bus time: 00H and codes 80H and above get 01H; a known code whose request contradicts itself
(quantity 0 or over the spec's limit, a byte count that doesn't match, truncated) gets 03H. Any
code the registry doesn't know still goes to the drive as it is."""

from __future__ import annotations

import pytest

from gateway.instruments.simulator import SimulatedLine
from tests.support import TcpClient, gateway_config, running_gateway

pytestmark = pytest.mark.line(addresses=[1])

STATE_WORD_1 = 0x2100


@pytest.mark.parametrize(
    ("request_hex", "answer_hex", "reason"),
    [
        ("00 00 01", "80 01", "function_code"),
        ("80 21 00 00 01", "80 01", "function_code"),
        ("C3 21 00 00 01", "C3 01", "function_code"),
        ("03 21 00 00 00", "83 03", "quantity"),  # quantity 0
        ("03 21 00 00 7E", "83 03", "quantity"),  # 126 > 125
        ("03 21 00", "83 03", "length"),  # truncated
        ("10 00 0B 00 01 00 00 00 00 00 00 00", "90 03", "byte_count"),  # count 0, 6 data bytes
        ("10 00 0B 00 02 04 00 01", "90 03", "byte_count"),  # 4 announced, 2 follow
        ("05 00 01 12 34", "85 03", "value"),  # a coil is FF00H or 0000H
        ("06 00 0B 00 01 00", "86 03", "length"),
    ],
)
async def test_a_malformed_request_is_answered_without_bus_time(
    line: SimulatedLine, request_hex: str, answer_hex: str, reason: str
) -> None:
    async with running_gateway(gateway_config(line.path, [{"name": "pump1", "address": 1}])) as app:
        client = await TcpClient.connect(app.tcp.port)
        assert await client.read(1, STATE_WORD_1) == [3]
        before = line.stats["requests"]
        assert await client.request(1, bytes.fromhex(request_hex)) == bytes.fromhex(answer_hex)
        assert line.stats["requests"] == before  # the line never saw it
        assert app.tcp.stats.malformed_requests[reason] == 1
        assert await client.read(1, STATE_WORD_1) == [3]  # the connection is still good
        await client.close()


async def test_unknown_codes_still_reach_the_drive(line: SimulatedLine) -> None:
    async with running_gateway(gateway_config(line.path, [{"name": "pump1", "address": 1}])) as app:
        client = await TcpClient.connect(app.tcp.port)
        before = line.stats["requests"]
        # 41H: a vendor code the registry doesn't know: the drive's own answer (01H) comes back.
        assert await client.request(1, bytes.fromhex("41 00 01")) == bytes.fromhex("C1 01")
        assert line.stats["requests"] == before + 1
        assert sum(app.tcp.stats.malformed_requests.values()) == 0
        await client.close()
