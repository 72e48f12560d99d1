"""Any polled value charted over a window: the store's history across a real restart of the
gateway (the same file closed and opened again), read through the console's JSON API over real
HTTP, as JSON and as CSV; the live window from the console's own ring; bad asks refused naming
the key. And the traffic monitor's ring, kept while nobody watches, with each attempt's time
split into queue wait, wire and the drive's turnaround."""

from __future__ import annotations

import asyncio
import csv
import io
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import aiohttp

from gateway.config import GatewayConfig, StorageConfig
from gateway.console.history import MAX_STORE_QUERIES, MAX_WAITING_QUERIES
from gateway.instruments.simulator import SimulatedLine
from gateway.store.history import Value
from gateway.store.records import HistoryPoint
from tests.support import (
    RecordProperty,
    TcpClient,
    eventually,
    free_port,
    present,
    read_pdu,
    running_gateway,
    write_many,
)
from tests.support.console_support import (
    OPERATOR_TOKEN,
    USERS,
    VIEWER_PASSWORD,
    console_client,
    console_config,
)
from tests.support.processes import gateway_process
from tests.support.store import running_store

CONTROL_WORD = 0x2000
RUN_FORWARD = 1
HUNDREDTHS = 100
STATE_WORD_1 = 0x2100


def with_history(line: SimulatedLine, store: Path) -> GatewayConfig:
    config = console_config(line.path)
    storage = {"path": str(store), "history_step_s": 1, "history_days": 7}
    return GatewayConfig.model_validate({**config.model_dump(), "storage": storage})


async def test_the_history_survives_a_restart_and_is_charted_and_downloaded(
    line: SimulatedLine, tmp_path: Path
) -> None:
    config = with_history(line, tmp_path / "events.db")
    async with running_gateway(config) as app:
        # SCADA runs pump1 at 30 Hz: the history has its frequency climbing and holding.
        client = await TcpClient.connect(app.tcp.port)
        await client.request(1, write_many(CONTROL_WORD, RUN_FORWARD, 30 * HUNDREDTHS))
        await client.close()
        await eventually(lambda: _hertz(app) > 0, 10.0, "pump1 running")

        async def three_steps() -> bool:
            return await _steps(app) >= 3

        await eventually(three_steps, 10.0, "three history steps of pump1 with it running")
        stopped_at = time.time()
    async with running_gateway(config) as app, console_client(app) as web:
        assert (await web.login("victor", VIEWER_PASSWORD)).status == 200
        found = await web.get_json(
            "/api/drives/pump1/history?keys=output_frequency_hz,state&window=1h"
        )
        assert found["source"] == "store"
        assert found["step_s"] == 1.0
        assert found["keys"] == ["time", "output_frequency_hz", "state"]
        times, hertz, states = found["columns"]
        before = [i for i, at in enumerate(times) if at < stopped_at]
        assert len(before) >= 3, found  # what the first run kept, read by the second
        assert times == sorted(times)
        # A step before the first poll of the running values has none: a gap, not a zero.
        assert max(hertz[i] or 0.0 for i in before) > 0
        assert "running_forward" in {states[i] for i in before}
        assert "output_current_a" in found["available"]
        assert "state" in found["text_values"]

        # Fewer points asked for than the window holds: neighbours merged, the span says so.
        merged = await web.get_json(
            "/api/drives/pump1/history?keys=output_frequency_hz&window=1h&points=2"
        )
        assert len(merged["columns"][0]) <= 2
        assert merged["step_s"] > 1.0

        async with web.session.get(
            f"{web.base}/api/drives/pump1/history?keys=output_frequency_hz&window=1h&format=csv"
        ) as response:
            assert response.status == 200
            assert response.headers["Content-Type"].startswith("text/csv")
            assert "attachment" in response.headers["Content-Disposition"]
            rows = list(csv.reader(io.StringIO(await response.text())))
        assert rows[0] == ["time", "output_frequency_hz"]
        assert len(rows) - 1 == len(times)
        first = datetime.fromisoformat(rows[1][0])
        assert first.tzinfo is not None
        assert abs(first.timestamp() - times[0]) < 0.001
        assert float(rows[1][1]) == hertz[0]

        # The last 15 minutes come from the console's live ring, a point a second. Asked once
        # the running values have been polled since the restart (the state words come first:
        # on a loaded machine a live point may have none yet, and the drive then has no
        # frequency to show in that window).
        await eventually(
            lambda: bool(
                present(app.console).console
                and _live_points(app)
                and "output_frequency_hz" in app.poller.telemetry("pump1")
            ),
            5.0,
        )
        live = await web.get_json("/api/drives/pump1/history?keys=output_frequency_hz&window=15m")
        assert live["source"] == "live"
        assert live["step_s"] == 1.0
        assert all(at >= stopped_at for at in live["columns"][0])


def _hertz(app: Any) -> float:
    value = app.poller.telemetry("pump1").get("output_frequency_hz")
    return float(value) if isinstance(value, int | float) else 0.0


async def _steps(app: Any) -> int:
    """History steps of pump1 (written or waiting for the disk) with the drive running."""
    points = await app.events.history_points("pump1", 0.0, time.time() + 1)
    return sum(1 for _, found in points if found.get("state") == "running_forward")


def _live_points(app: Any) -> int:
    return len(app.console.console.live.history["pump1"].points)


async def test_a_bad_ask_is_refused_naming_the_key(line: SimulatedLine, tmp_path: Path) -> None:
    config = with_history(line, tmp_path / "events.db")
    async with running_gateway(config) as app, console_client(app) as web:
        assert (await web.login("victor", VIEWER_PASSWORD)).status == 200
        await eventually(lambda: bool(app.poller.telemetry("pump1")), 5.0)
        asks = {
            "keys=no_such_value": "keys: pump1 has no value 'no_such_value'",
            "keys=a;b": "keys: 'a;b' is not a value's name",
            "window=3w": "window: one of 15m, 1h, 6h, 24h, 7d",
            "since=2026-01-01T00:00:00": "since: an ISO 8601 time with its zone",
            "since=2026-01-02T00:00:00Z&until=2026-01-01T00:00:00Z": "since: must be before",
            "points=many": "points: a whole number",
            "points=0": "points: a whole number, 1 to 5000",
            "points=-5": "points: a whole number, 1 to 5000",
            "points=5001": "points: a whole number, 1 to 5000",
            "points=1000000000": "points: a whole number, 1 to 5000",
        }
        for ask, reason in asks.items():
            async with web.session.get(f"{web.base}/api/drives/pump1/history?{ask}") as response:
                assert response.status == 400, ask
                assert reason in (await response.json())["error"], ask
        async with web.session.get(f"{web.base}/api/drives/nobody/history") as response:
            assert response.status == 404


DAY_S = 86400.0


async def test_a_months_window_is_reduced_in_the_store_and_queries_are_bounded(
    line: SimulatedLine, tmp_path: Path, record_property: RecordProperty
) -> None:
    # 30 days of pump1 at a point a minute, kept by the store as the service keeps them.
    storage = StorageConfig(path=str(tmp_path / "events.db"), history_days=90, history_step_s=60)
    until = time.time() - time.time() % 60
    since = until - 30 * DAY_S
    async with running_store(storage) as store:
        for n in range(int(30 * DAY_S / 60)):
            state = "running_forward" if n % 2 else "stopped"
            values: dict[str, Value] = {"output_frequency_hz": float(n % 4), "state": state}
            store.history.keep(HistoryPoint("pump1", since + 60 * n, values))
            if n % 5000 == 4999:
                await store.flush()
        await store.flush()
    config = console_config(line.path)
    config = GatewayConfig.model_validate({**config.model_dump(), "storage": storage.model_dump()})
    async with running_gateway(config) as app, console_client(app) as web:
        assert (await web.login("victor", VIEWER_PASSWORD)).status == 200
        window = f"since={iso(since)}&until={iso(until)}&keys=output_frequency_hz,state"
        started = time.monotonic()
        found = await web.get_json(f"/api/drives/pump1/history?{window}&points=600")
        took_s = time.monotonic() - started
        times, hertz, states = found["columns"]
        assert found["source"] == "store"
        assert len(times) <= 600
        assert found["step_s"] == 4380.0  # 73 minutes: 30 days in 593 points, aligned
        assert times == sorted(times)
        # Each point the mean of its 73 minutes of 0, 1, 2, 3 Hz in turn.
        assert all(1.47 < h < 1.53 for h in hertz[1:-1]), hertz
        assert set(states) <= {"running_forward", "stopped"}

        # Twenty at once (a dashboard of many charts): two read the store at a time, eight
        # wait their turn, the rest are told to come back (503), none is lost in a queue.
        async def one() -> int:
            ask = f"{web.base}/api/drives/pump1/history?{window}&points=5000"
            async with web.session.get(ask) as response:
                await response.read()
                if response.status == 503:
                    assert response.headers["Retry-After"] == "1"
                return response.status

        statuses = await asyncio.gather(*(one() for _ in range(20)))
        assert set(statuses) <= {200, 503}, statuses
        assert statuses.count(200) >= MAX_STORE_QUERIES + MAX_WAITING_QUERIES, statuses
        record_property(
            "figure:console history 30 days",
            f"43,200 points of pump1 reduced in the store to {len(times)} in {took_s:.2f} s; "
            f"20 at once: {statuses.count(200)} answered, {statuses.count(503)} told 503",
        )


def iso(at: float) -> str:
    return datetime.fromtimestamp(at, UTC).isoformat().replace("+00:00", "Z")


async def test_the_monitor_keeps_the_last_transactions_while_nobody_watches(
    line: SimulatedLine,
) -> None:
    line.set_reply_delay(1, 20.0)  # pump1 answers 20 ms after the request's last byte
    async with running_gateway(console_config(line.path)) as app:
        client = await TcpClient.connect(app.tcp.port)
        assert await client.request(1, read_pdu(STATE_WORD_1)) == bytes.fromhex("03 02 00 03")
        await client.close()
        line.set_dead(2)
        await eventually(lambda: _timeouts(app) > 0, 5.0, "a timeout of fan2 recorded")
        # Only now does anybody open the monitor: what happened before is there.
        headers = {"Authorization": f"Bearer {OPERATOR_TOKEN}"}
        async with (
            console_client(app) as web,
            web.session.get(
                f"{web.base}/api/buses/line1/traffic?recent=2000", headers=headers
            ) as response,
        ):
            assert response.status == 200
            records = await _until_watching(response)
    read = next(r for r in records if r["client"].startswith("tcp:"))
    assert read["meaning"] == "read 2100H state word 1 → 0003H stopped"
    # 115200 baud, 8E1: 11 bits a byte; the request 8 bytes, the reply 7.
    assert abs(read["wire_ms"] - 15 * 11 / 115200 * 1000) < 0.01
    assert 19.0 <= read["turnaround_ms"] <= read["latency_ms"], read
    assert read["queue_ms"] >= 0.0
    timeout = next(r for r in records if r["drive"] == "fan2" and r["outcome"].endswith("timeout"))
    assert timeout["turnaround_ms"] is None  # no reply, no turnaround
    assert abs(timeout["wire_ms"] - 8 * 11 / 115200 * 1000) < 0.01


def _timeouts(app: Any) -> int:
    ring = app.console.console.traffic.recent("line1")
    return sum(1 for record in ring if record.outcome == "timeout")


async def _until_watching(response: Any) -> list[dict[str, Any]]:
    import json

    records: list[dict[str, Any]] = []
    event = ""
    async for raw in response.content:
        line = raw.decode().rstrip("\n")
        if line.startswith("event: "):
            event = line.removeprefix("event: ")
        elif line.startswith("data: ") and event == "traffic":
            records.append(json.loads(line.removeprefix("data: ")))
        elif line.startswith("data: ") and event == "watching":
            return records
    raise AssertionError("the stream ended before it said it was watching")


async def test_the_history_survives_a_restart_of_the_service(
    line: SimulatedLine, tmp_path: Path
) -> None:
    """`invt-gateway run` stopped by SIGTERM and started again on the same store: the second
    process serves what the first one kept."""
    port = free_port()
    config = {
        "modbus_tcp": {"host": "127.0.0.1", "port": free_port()},
        "buses": [{"name": "line1", "port": line.path, "baudrate": 115200, "timeout_ms": 100}],
        "drives": [{"name": "pump1", "bus": "line1", "address": 1}],
        "storage": {"path": str(tmp_path / "events.db"), "history_step_s": 1},
        "console": {
            "enabled": True,
            "host": "127.0.0.1",
            "port": port,
            "users": USERS,
        },
    }
    with gateway_process(config, tmp_path) as first:
        await asyncio.to_thread(first.wait_ready)
        await asyncio.sleep(3.5)  # three history steps, a second each: the service's own pace
        first.stop()
    stopped_at = time.time()
    assert first.process.returncode == 0
    with gateway_process(config, tmp_path) as second:
        await asyncio.to_thread(second.wait_ready)
        headers = {"Authorization": f"Bearer {OPERATOR_TOKEN}"}
        async with (
            aiohttp.ClientSession() as session,
            session.get(
                f"http://127.0.0.1:{port}/api/drives/pump1/history?window=1h&keys=state",
                headers=headers,
            ) as response,
        ):
            assert response.status == 200
            found = await response.json()
    times, states = found["columns"]
    kept = [state for at, state in zip(times, states, strict=True) if at < stopped_at]
    assert len(kept) >= 2, found
    assert set(kept) == {"stopped"}
