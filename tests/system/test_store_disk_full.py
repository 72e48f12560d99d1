"""A store on a disk that fills up: events still reach the broker (from memory), the store stays
within what the disk has, says so in /health and /metrics while it can't write, and writes what
waited once space is back, without a restart.

The store is on a 2 MB tmpfs of its own with the default bounds (`storage.max_mb: 64`, far more
than the disk has); "a runaway log" fills the disk and is removed again.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import sqlite3
from collections.abc import Callable
from pathlib import Path
from typing import Any

from gateway.app import Application
from gateway.config import ConsoleConfig, MetricsConfig, StorageConfig
from gateway.store import EventType
from tests.support import eventually, free_port, running_gateway
from tests.support.console_support import console_client
from tests.support.http import Scrape, http_get
from tests.support.mosquitto import MqttProbe, mqtt_probe, running_mosquitto, unique_base_topic
from tests.support.mqtt_setup import mqtt_config, simulated_line
from tests.support.small_disk import fill, free_bytes, small_disk

BURST = 20


async def record(app: Application, phase: str, count: int) -> None:
    """`count` events, a burst at a time, as a plant's commands and faults would come."""
    for n in range(count):
        app.events.record(EventType.COMMAND, {"phase": phase, "n": n, "pad": "x" * 200})
        if n % BURST == BURST - 1:
            await asyncio.sleep(0.02)


def received(probe: MqttProbe, topic: str, phase: str) -> list[dict[str, Any]]:
    events = [m.json() for m in probe.on(topic)]
    return [e for e in events if e["type"] == "command" and e["data"]["phase"] == phase]


def caught_up(probe: MqttProbe, topic: str, count: int) -> Callable[[], bool]:
    return lambda: len(received(probe, topic, "flood")) >= count


async def scrape(port: int) -> Scrape:
    _, _, text = await http_get(port, "/metrics")
    return Scrape(text)


async def health(port: int) -> dict[str, Any]:
    _, _, body = await http_get(port, "/health")
    report: dict[str, Any] = json.loads(body)
    return report


def stored_phases(store: Path) -> dict[str, list[int]]:
    """What an operator's sqlite3 reads from the file: each phase's `n`s, in id order."""
    with contextlib.closing(sqlite3.connect(f"file:{store}?mode=ro", uri=True)) as db:
        rows = db.execute("SELECT data FROM events WHERE type = 'command' ORDER BY id").fetchall()
    phases: dict[str, list[int]] = {}
    for (data,) in rows:
        event = json.loads(data)
        phases.setdefault(event["phase"], []).append(event["n"])
    return phases


async def test_events_reach_the_broker_while_the_disk_is_full_and_are_stored_once_freed(
    tmp_path: Path,
) -> None:
    base = unique_base_topic()
    topic = f"{base}/bridge/event"
    metrics_port = free_port()
    with (
        small_disk(tmp_path / "disk") as disk,
        running_mosquitto(tmp_path) as broker,
        simulated_line() as line,
    ):
        store = disk / "events.db"
        config = mqtt_config(line.path, broker, base, homeassistant_discovery=False)
        config = config.model_copy(
            update={
                "storage": StorageConfig(path=str(store)),  # max_mb: 64, the default
                "metrics": MetricsConfig(enabled=True, host="127.0.0.1", port=metrics_port),
                "console": ConsoleConfig(enabled=True, port=0, anonymous_view=True),
            }
        )
        async with (
            mqtt_probe(broker, topic) as probe,
            running_gateway(config) as app,
            console_client(app) as console,
        ):
            await record(app, "before", 100)
            await eventually(lambda: len(received(probe, topic, "before")) == 100, 15)
            assert (await health(metrics_port))["status"] == "ok"

            fill(disk / "runaway.log")
            await record(app, "full", 200)
            await eventually(lambda: len(received(probe, topic, "full")) == 200, 15, "from memory")
            report = await health(metrics_port)
            assert report["status"] == "degraded"
            assert "storage.path" in report["store"]["reason"]
            assert str(store) in report["store"]["reason"]
            banner = (await console.get_json("/api/overview"))["store_problem"]
            assert banner == report["store"]["reason"]  # the console's banner says it too
            metrics = await scrape(metrics_port)
            assert metrics("store_events_in_memory") == 200
            assert metrics("store_events_undelivered") == 0  # the broker has them all

            (disk / "runaway.log").unlink()
            await eventually(
                lambda: scrape_value(metrics_port, "store_events_in_memory", 0), 15, "written"
            )
            assert (await health(metrics_port))["status"] == "ok"
            assert (await console.get_json("/api/overview"))["store_problem"] is None
            await record(app, "after", 100)
            await eventually(lambda: len(received(probe, topic, "after")) == 100, 15)
            await app.events.flush()
            assert (await scrape(metrics_port))("store_events_dropped_total") == 0

            ids = [m.json()["id"] for m in probe.on(topic)]
            assert len(ids) == len(set(ids)), "an event went out twice"
            for phase, count in (("before", 100), ("full", 200), ("after", 100)):
                assert sorted(e["data"]["n"] for e in received(probe, topic, phase)) == list(
                    range(count)
                )
            assert ids == sorted(ids)
        phases = stored_phases(store)
        assert phases["full"] == list(range(200)), "what waited in memory was written"
        assert phases["after"] == list(range(100))
        assert free_bytes(disk) > 0


async def scrape_value(port: int, name: str, value: float) -> bool:
    return (await scrape(port))(name) == value


async def test_a_store_alone_on_a_small_disk_stays_within_it(tmp_path: Path) -> None:
    """Three times the disk in events, the broker connected: the store trims the oldest (the
    broker has them) to stay within the disk, leaving its reserve free; nothing fails, nothing
    the broker didn't have is dropped."""
    base = unique_base_topic()
    topic = f"{base}/bridge/event"
    metrics_port = free_port()
    with (
        small_disk(tmp_path / "disk") as disk,
        running_mosquitto(tmp_path) as broker,
        simulated_line() as line,
    ):
        store = disk / "events.db"
        config = mqtt_config(line.path, broker, base, homeassistant_discovery=False)
        config = config.model_copy(
            update={
                "storage": StorageConfig(path=str(store)),
                "metrics": MetricsConfig(enabled=True, host="127.0.0.1", port=metrics_port),
            }
        )
        async with mqtt_probe(broker, topic) as probe, running_gateway(config) as app:
            lowest_free = free_bytes(disk)
            for n in range(3000):  # about 6 MB of events on a 2 MB disk
                app.events.record(EventType.COMMAND, {"phase": "flood", "n": n, "pad": "x" * 2000})
                if n % BURST == BURST - 1:
                    # The broker keeps up: what goes to make room is what it has.
                    await eventually(caught_up(probe, topic, n + 1 - 5 * BURST), 15)
                    lowest_free = min(lowest_free, free_bytes(disk))
            await eventually(lambda: len(received(probe, topic, "flood")) == 3000, 15)
            await app.events.flush()
            metrics = await scrape(metrics_port)
            assert metrics("store_write_failures_total") == 0
            assert metrics("store_events_dropped_total") == 0
            assert (await health(metrics_port))["status"] == "ok"
            kept = stored_phases(store)["flood"]
        assert lowest_free >= 256 * 1024, "the store's reserve"
        assert 0 < len(kept) < 3000
        assert kept == list(range(3000 - len(kept), 3000)), "the newest kept"
        ids = [m.json()["id"] for m in probe.on(topic)]
        assert len(ids) == len(set(ids)) == 3000
