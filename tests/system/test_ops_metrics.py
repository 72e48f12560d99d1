"""Metrics and health scraped over real HTTP from a running gateway with real traffic on a pty
line."""

from __future__ import annotations

import asyncio
import json
import platform
from typing import Any

try:
    import uvloop
except ImportError:  # a box without its wheel: asyncio's loop
    uvloop = None  # type: ignore[assignment]

from gateway import ENGINE_ROOM, __version__
from gateway.app import Application
from gateway.compiled import COMPILED
from gateway.config import GatewayConfig
from gateway.instruments.simulator import SimulatedLine
from gateway.metrics import MetricsFeature
from gateway.settings import runtime_settings
from tests.support import TcpClient, free_port, read_pdu, running_gateway, write_pdu
from tests.support.http import Scrape, http_get

STATE_WORD_1 = 0x2100
TIMEOUT_S = 0.1


def metrics_config(port: str, metrics_port: int) -> GatewayConfig:
    return GatewayConfig.model_validate(
        {
            "gateway_id": "cabinet-test",
            "modbus_tcp": {"host": "127.0.0.1", "port": 0},
            "buses": [
                {
                    "name": "line1",
                    "port": port,
                    "baudrate": 115200,
                    "timeout_ms": TIMEOUT_S * 1000,
                    "retries": 1,
                    "offline_after": 1,
                    "probe_max_s": 60,
                }
            ],
            "drives": [
                {"name": "pump1", "bus": "line1", "address": 1, "model": "gd350"},
                {"name": "fan2", "bus": "line1", "address": 2, "model": "gd20"},
                {"name": "ghost", "bus": "line1", "address": 9, "model": "gd20"},
            ],
            "metrics": {"enabled": True, "host": "127.0.0.1", "port": metrics_port},
        }
    )


async def test_metrics_count_real_traffic_per_drive_source_and_code(line: SimulatedLine) -> None:
    metrics_port = free_port()
    async with running_gateway(metrics_config(line.path, metrics_port)) as app:
        client = await TcpClient.connect(app.tcp.port)
        for _ in range(5):
            assert await client.read(1, STATE_WORD_1) == [3]
        # P00.01 = 3 is out of range: the drive's own exception 04H.
        assert await client.request(2, write_pdu(0x0001, 3)) == bytes.fromhex("86 04")
        # Nobody at address 9: two attempts time out, 0BH, and the drive is offline.
        assert await client.request(9, read_pdu(STATE_WORD_1)) == bytes.fromhex("83 0b")
        # Every reply's CRC spoilt: a framing error, counted by kind.
        line.set_line_faults(rate=1.0, kinds=["crc"])
        assert await client.request(2, read_pdu(STATE_WORD_1)) == bytes.fromhex("83 0b")
        line.set_line_faults(rate=0.0)

        status, content_type, text = await http_get(metrics_port, "/metrics")
        assert status == 200
        assert content_type.startswith("text/plain")
        m = Scrape(text)
        bus = {"bus": "line1"}
        pump, fan, ghost = ({**bus, "drive": name} for name in ("pump1", "fan2", "ghost"))

        # Per request, by source and function code, with latency.
        assert m("requests_total", **pump, source="tcp", function="03") == 5
        assert m("requests_total", **fan, source="tcp", function="06") == 1
        assert m("request_exceptions_total", **fan, source="tcp", code="04") == 1
        assert m("request_exceptions_total", **ghost, source="tcp", code="0B") == 1
        assert m("request_duration_seconds_count", **pump, source="tcp") == 5
        # The dead drive's answer took both attempts' timeouts.
        ghost_latency = m("request_duration_seconds_sum", **ghost, source="tcp")
        assert ghost_latency >= 2 * TIMEOUT_S
        # The histogram sorts them: the healthy reads below the dead drive's 2 timeouts.
        assert m("request_duration_seconds_bucket", **pump, source="tcp", le="+Inf") == 5
        assert m("request_duration_seconds_sum", **pump, source="tcp") < ghost_latency

        # Per drive, from the line's own counters.
        assert m("drive_timeouts_total", **ghost) == 2
        assert m("drive_retries_total", **ghost) == 1
        assert m("drive_failed_total", **ghost) == 1
        assert m("drive_exceptions_total", **fan, code="04") == 1
        assert m("drive_bad_replies_total", **fan, kind="crc") == 2
        assert m("drive_online", **pump) == 1
        assert m("drive_online", **ghost) == 0
        assert m("drive_info", **pump, address="1", unit_id="1", model="gd350") == 1
        assert m("drive_busy_seconds_total", **ghost) >= 2 * TIMEOUT_S

        # Per bus.
        assert m("bus_requests_total", **bus) == 8
        assert m("bus_timeouts_total", **bus) == 2
        assert m("bus_retries_total", **bus) == 2
        assert m("bus_failed_total", **bus) == 2
        assert m("bus_state", **bus, state="open") == 1
        assert m("bus_state", **bus, state="reopening") == 0
        assert m("bus_queue_depth", **bus) == 0
        busy = m("bus_busy_seconds_total", **bus)
        exchange = m("bus_exchange_seconds_total", **bus)
        assert busy >= 2 * TIMEOUT_S + exchange  # timeouts hold the line too
        assert 0 < exchange < 1

        # The gateway and its TCP side.
        assert m("tcp_clients") == 1
        assert m("tcp_requests_total") == 8
        assert m("ready") == 1
        # The loop is the one this test runs on (in-process): uvloop where it is installed.
        # Known by what it is, not by its class's module: the tests' uvloop loops are a
        # subclass of uvloop's (tests/conftest.py).
        running = asyncio.get_running_loop()
        loop = "uvloop" if uvloop is not None and isinstance(running, uvloop.Loop) else "asyncio"
        build = {
            "gateway_id": "cabinet-test",
            "version": __version__,
            "python": platform.python_version(),
        }
        assert m("build_info", **build, event_loop=loop) == 1
        assert m("engine_room_compiled") == (1 if ENGINE_ROOM == COMPILED else 0)
        assert m("process_resident_memory_bytes") > 0
        await client.close()


async def test_health_is_json_and_tells_ready_from_degraded(line: SimulatedLine) -> None:
    metrics_port = free_port()
    async with running_gateway(metrics_config(line.path, metrics_port)) as app:
        status, content_type, body = await http_get(metrics_port, "/health")
        assert (status, content_type) == (200, "application/json")
        report: dict[str, Any] = json.loads(body)
        assert report["status"] == "ok"
        assert report["ready"] is True
        assert report["live"] is True
        assert report["gateway_id"] == "cabinet-test"
        assert report["buses"]["line1"]["state"] == "open"
        assert report["buses"]["line1"]["drives_online"] == ["pump1", "fan2", "ghost"]

        client = await TcpClient.connect(app.tcp.port)
        assert await client.request(9, read_pdu(STATE_WORD_1)) == bytes.fromhex("83 0b")
        status, _, body = await http_get(metrics_port, "/health/ready")
        report = json.loads(body)
        # An offline drive is worth an alert, not a restart: still ready, but degraded.
        assert status == 200
        assert report["status"] == "degraded"
        assert report["buses"]["line1"]["drives_offline"] == ["ghost"]
        assert report["tcp_clients"] == 1

        status, _, body = await http_get(metrics_port, "/health/live")
        assert status == 200
        assert json.loads(body)["live"] is True
        status, _, body = await http_get(metrics_port, "/nothing-here")
        assert status == 404
        assert "/metrics" in body
        await client.close()


async def test_health_is_503_until_the_gateway_is_started(line: SimulatedLine) -> None:
    metrics_port = free_port()
    app = Application(runtime_settings(metrics_config(line.path, metrics_port)))
    assert app.settings.metrics is not None
    feature = MetricsFeature(app, app.settings.metrics)
    await feature.start()
    try:
        status, _, body = await http_get(metrics_port, "/health")
        assert status == 503
        assert json.loads(body)["status"] == "starting"
        status, _, _ = await http_get(metrics_port, "/health/live")
        assert status == 200
    finally:
        await feature.stop()


async def test_clients_can_not_choose_label_values(line: SimulatedLine) -> None:
    metrics_port = free_port()
    async with running_gateway(metrics_config(line.path, metrics_port)) as app:
        client = await TcpClient.connect(app.tcp.port)
        # Thirty vendor or unassigned function codes: the drive answers each with 01H.
        for function in range(0x41, 0x5F):
            answer = await client.request(1, bytes((function, 0x00)))
            assert answer == bytes((function | 0x80, 0x01))
        # A broadcast write: its own series, never a "drive".
        assert await client.request(0, write_pdu(0x2000, 5)) == write_pdu(0x2000, 5)
        await client.close()
        _, _, text = await http_get(metrics_port, "/metrics")
    m = Scrape(text)
    functions = {
        dict(labels)["function"]
        for (name, labels) in m.samples
        if name == "invt_gateway_requests_total"
    }
    assert functions == {"other", "08"} or functions == {"other"}  # 08H: the gateway's probes
    assert m("requests_total", bus="line1", drive="pump1", source="tcp", function="other") == 30
    drives = {dict(labels).get("drive") for (_, labels) in m.samples}
    assert "broadcast" not in drives
    assert m("broadcast_requests_total", bus="line1", source="tcp", function="06") == 1


async def test_excess_gap_counts_back_to_back_transactions_and_never_goes_below_t35(
    line: SimulatedLine,
) -> None:
    """`bus_excess_gap_seconds`: the silence the gateway adds beyond t3.5 when a request was
    already waiting for the line as the gap after a reply ended. A client that pauses longer
    than the gap between its requests is not counted: the line waited for it."""
    metrics_port = free_port()
    async with running_gateway(metrics_config(line.path, metrics_port)) as app:
        alone = await TcpClient.connect(app.tcp.port)
        for _ in range(5):
            assert await alone.read(1, STATE_WORD_1) == [3]
            await asyncio.sleep(10 * line.t35_s)
        m = Scrape((await http_get(metrics_port, "/metrics"))[2])
        bus = {"bus": "line1"}
        assert m("bus_excess_gap_seconds_count", **bus) == 0  # nobody waited for the line

        clients = [await TcpClient.connect(app.tcp.port) for _ in range(4)]

        async def reads(client: TcpClient, unit: int, words: int) -> None:
            for _ in range(15):  # each client its own read: none joins another's transaction
                assert (await client.request(unit, read_pdu(STATE_WORD_1, words)))[0] == 3

        await asyncio.gather(*(reads(c, 1 + i % 2, 1 + i // 2) for i, c in enumerate(clients)))
        m = Scrape((await http_get(metrics_port, "/metrics"))[2])
        counted = m("bus_excess_gap_seconds_count", **bus)
        transactions = m("bus_transactions_total", **bus)
        # Four clients keep the queue full: most of their 60 reads follow a reply back to back
        # (the lone client's reads before them did not wait).
        assert 30 <= counted <= transactions - 5
        assert m("bus_excess_gap_seconds_bucket", **bus, le="+Inf") == counted
        # The first bucket (le 0) holds gaps shorter than t3.5: there must be none.
        assert m("bus_excess_gap_seconds_bucket", **bus, le="0.0") == 0
        assert m("bus_excess_gap_seconds_sum", **bus) > 0
        # The line learnt to wake before each gap's end (its wake-ups came late), and what
        # waiting out the rest on the clock cost is counted, a fraction of the line's time.
        assert m("line_gap_lead_seconds", **bus) > 0
        spun = m("line_gap_spin_seconds_total", **bus)
        assert 0 <= spun < m("bus_busy_seconds_total", **bus) / 10
        # The drives' side agrees: no request came less than t3.5 after the previous frame.
        stats = line.stats
        assert stats["gap_violations"] == 0
        assert stats["min_gap_s"] >= line.t35_s
        for client in (alone, *clients):
            await client.close()
