"""`invt-gateway monitor`: the traffic monitor in a terminal, as a real subprocess against the
gateway on the simulated line."""

from __future__ import annotations

import asyncio
import os
import re

from gateway.instruments.simulator import SimulatedLine
from tests.support import TcpClient, present, read_pdu, running_gateway
from tests.support.console_support import OPERATOR_TOKEN, console_config
from tests.support.processes import entry_point, run_cli


async def test_monitor_prints_a_scada_read_in_words(line: SimulatedLine) -> None:
    async with running_gateway(console_config(line.path)) as app:
        url = f"http://127.0.0.1:{present(app.console).port}"
        process = await asyncio.create_subprocess_exec(
            *(entry_point(), "monitor", "--url", url, "--bus", "line1", "--recent", "0"),
            stdin=asyncio.subprocess.DEVNULL,
            stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.PIPE,
            env={**os.environ, "INVT_GATEWAY_CONSOLE_TOKEN": OPERATOR_TOKEN},
        )
        try:
            assert process.stderr is not None
            assert process.stdout is not None
            watching = await line_with(process.stderr, "watching")
            assert watching == f"watching line1 at {url} (Ctrl-C to stop)"
            client = await TcpClient.connect(app.tcp.port)
            await client.request(1, read_pdu(0x2100))
            await client.close()
            printed = await line_with(process.stdout, "tcp:127.0.0.1")
            assert "unit   1 pump1" in printed
            assert "03H  read 2100H state word 1 → 0003H stopped  [ok," in printed
            assert re.search(r"ms: queue [\d.]+, wire 1\.43, drive [\d.]+\]$", printed), printed
        finally:
            process.terminate()
            await asyncio.wait_for(process.wait(), 5)


async def line_with(stream: asyncio.StreamReader, text: str, within_s: float = 10.0) -> str:
    async with asyncio.timeout(within_s):
        while True:
            line = (await stream.readline()).decode()
            assert line, f"the monitor ended before printing {text!r}"
            if text in line:
                return line.rstrip("\n")


async def test_monitor_without_a_token_says_why_and_exits_1(line: SimulatedLine) -> None:
    async with running_gateway(console_config(line.path)) as app:
        url = f"http://127.0.0.1:{present(app.console).port}"
        result = await asyncio.to_thread(run_cli, "monitor", "--url", url)
    assert result.returncode == 1
    assert "401" in result.stderr
    assert "send an API token" in result.stderr
