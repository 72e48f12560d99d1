"""What the gateway writes to its log for a person on call: every frame at debug level, each fault
raised and cleared, and JSON lines for journald or Loki from a real process."""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import signal
from collections.abc import Iterator
from pathlib import Path

import pytest

from gateway.instruments.simulator import SimulatedLine
from tests.support import TcpClient, free_port, gateway_config, read_pdu, running_gateway
from tests.support.mosquitto import Mosquitto, unique_base_topic
from tests.support.mqtt_setup import mqtt_config, simulated_line
from tests.support.processes import gateway_process

pytestmark = pytest.mark.line(addresses=[1])

STATE_WORD_1 = 0x2100


DRIVES = [{"name": "pump1", "address": 1}, {"name": "ghost", "address": 9}]


async def test_debug_level_hex_dumps_every_frame(
    line: SimulatedLine, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.DEBUG, logger="gateway.frames")
    async with running_gateway(gateway_config(line.path, DRIVES)) as app:
        client = await TcpClient.connect(app.tcp.port)
        assert await client.read(1, STATE_WORD_1) == [3]
        assert await client.request(9, read_pdu(STATE_WORD_1)) == bytes.fromhex("83 0b")
        await client.close()
    dumps = [r.getMessage() for r in caplog.records if r.name == "gateway.frames"]
    # PROTOCOL.md's frames, byte for byte: the request and the drive's reply.
    assert "line1 tx 01 03 21 00 00 01 8e 36" in dumps
    assert "line1 rx 01 03 02 00 03 f8 45" in dumps
    assert "line1 rx timeout (nothing)" in dumps


async def test_no_frame_dump_above_debug(
    line: SimulatedLine, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, logger="gateway.frames")
    async with running_gateway(gateway_config(line.path, DRIVES)) as app:
        client = await TcpClient.connect(app.tcp.port)
        assert await client.read(1, STATE_WORD_1) == [3]
        await client.close()
    assert not [r for r in caplog.records if r.name == "gateway.frames"]


async def test_frame_dumps_follow_the_level_while_the_gateway_runs(
    line: SimulatedLine, caplog: pytest.LogCaptureFixture
) -> None:
    """The level changed under a running gateway (as a reload or an operator's `setLevel`
    does) turns the dumps on and off at the next frame: the bus's cheap check of logging's
    remembered answer never keeps a stale one."""
    caplog.set_level(logging.DEBUG, logger="gateway.frames")  # the capture takes all
    frames = logging.getLogger("gateway.frames")
    frames.setLevel(logging.INFO)  # caplog puts the level back afterwards

    def dumps() -> list[str]:
        return [r.getMessage() for r in caplog.records if r.name == "gateway.frames"]

    async with running_gateway(gateway_config(line.path, DRIVES)) as app:
        client = await TcpClient.connect(app.tcp.port)
        assert await client.read(1, STATE_WORD_1) == [3]
        assert dumps() == []
        frames.setLevel(logging.DEBUG)
        assert await client.read(1, STATE_WORD_1) == [3]
        assert "line1 rx 01 03 02 00 03 f8 45" in dumps()
        frames.setLevel(logging.INFO)
        seen = len(dumps())
        assert await client.read(1, STATE_WORD_1) == [3]
        assert len(dumps()) == seen
        await client.close()


class LogWatch(logging.Handler):
    """Sets `seen` when a record with `text` is logged (records come from the event loop)."""

    def __init__(self, text: str) -> None:
        super().__init__()
        self.text = text
        self.seen = asyncio.Event()

    def emit(self, record: logging.LogRecord) -> None:
        if self.text in record.getMessage():
            self.seen.set()


@contextlib.contextmanager
def watching(logger: str, text: str) -> Iterator[LogWatch]:
    watch = LogWatch(text)
    logging.getLogger(logger).addHandler(watch)
    try:
        yield watch
    finally:
        logging.getLogger(logger).removeHandler(watch)


async def test_fault_raised_and_cleared_are_logged(
    mosquitto: Mosquitto, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.INFO, logger="gateway.event_log")
    fault = "STo: maladjustment (code 35)"
    with simulated_line() as sim:
        config = mqtt_config(sim.path, mosquitto, unique_base_topic())
        async with running_gateway(config):
            with watching("gateway.event_log", f"drive pump1: fault raised: {fault}") as raised:
                sim.inject_fault(1, 35)
                await asyncio.wait_for(raised.seen.wait(), 5.0)
            with watching("gateway.event_log", f"drive pump1: fault cleared: {fault}") as cleared:
                sim.clear_fault(1)
                await asyncio.wait_for(cleared.seen.wait(), 5.0)
    record = next(r for r in caplog.records if "fault raised" in r.getMessage())
    assert record.levelno == logging.WARNING


def test_json_log_lines_from_a_real_process(line: SimulatedLine, tmp_path: Path) -> None:
    config = {
        "modbus_tcp": {"host": "127.0.0.1", "port": free_port()},
        "buses": [{"name": "line1", "port": line.path, "baudrate": 115200}],
        "logging": {"level": "debug", "format": "json"},
    }
    with gateway_process(config, tmp_path) as gateway:
        gateway.wait_ready()
        gateway.signal(signal.SIGTERM)
        assert gateway.wait(2.0) == 0
    entries = [json.loads(line) for line in gateway.log.lines]
    assert {"time", "level", "logger", "message"} <= entries[0].keys()
    assert any(e["message"].startswith("ready:") and e["level"] == "info" for e in entries)
    assert any(e["message"] == "SIGTERM received: shutting down" for e in entries)


async def test_a_flood_of_malformed_frames_logs_one_line_and_counts_them_all(
    line: SimulatedLine, tmp_path: Path
) -> None:
    port, metrics = free_port(), free_port()
    config = {
        "modbus_tcp": {"host": "127.0.0.1", "port": port},
        "buses": [{"name": "line1", "port": line.path, "baudrate": 115200}],
        "drives": [{"name": "pump1", "bus": "line1", "address": 1}],
        "metrics": {"enabled": True, "host": "127.0.0.1", "port": metrics},
    }
    with gateway_process(config, tmp_path) as gateway:
        gateway.wait_ready()
        for _ in range(200):  # protocol id 7: malformed, the connection is closed
            reader, writer = await asyncio.open_connection("127.0.0.1", port)
            writer.write(bytes.fromhex("0001 0007 0006 01 03 2100 0001"))
            assert await asyncio.wait_for(reader.read(), 5) == b""
            writer.close()
        # A served client is unaffected.
        client = await TcpClient.connect(port)
        assert await client.read(1, STATE_WORD_1) == [3]
        await client.close()
        reader, writer = await asyncio.open_connection("127.0.0.1", metrics)
        writer.write(b"GET /metrics HTTP/1.0\r\n\r\n")
        body = (await asyncio.wait_for(reader.read(), 5)).decode()
        writer.close()
        gateway.signal(signal.SIGTERM)
        assert gateway.wait(5.0) == 0
    malformed_lines = [text for text in gateway.log.lines if "malformed frame" in text]
    assert len(malformed_lines) == 1, malformed_lines  # the first at once, the rest held back
    assert "invt_gateway_tcp_malformed_total 200.0" in body  # every one counted


def test_repeats_pass_once_a_window_with_their_count() -> None:
    from gateway.logs import RepeatFilter, repeated

    repeats = RepeatFilter(window_s=60)
    logger = logging.getLogger("test.repeats")

    def record(at: float, source: str | None = "tcp-malformed") -> logging.LogRecord:
        extra = repeated(source) if source else {}
        made = logger.makeRecord(
            "test", logging.WARNING, "x", 1, "closed: %s", ("bad",), None, extra=extra
        )
        made.created = at
        return made

    assert repeats.filter(record(1000.0))  # the first at once
    assert not any(repeats.filter(record(1000.0 + n)) for n in range(1, 50))  # 49 held back
    assert repeats.held_back() == {"tcp-malformed": 49}
    assert repeats.filter(record(1000.0 + 10, source=None))  # unmarked records always pass
    late = record(1061.0)
    assert repeats.filter(late)  # the window is over: passes, with the count of the others
    assert late.getMessage().startswith("closed: bad (49 more like this since ")
