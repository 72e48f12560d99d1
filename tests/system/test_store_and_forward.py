"""Nothing lost: events raised while the broker is down wait in the store, through a SIGKILL of
the gateway, and reach a dashboard once the broker is back, in id order; a store past its size
bound keeps the newest; fault history read back over MQTT after a restart.

A real Mosquitto with persistence stands for the plant's broker: the dashboard's session (QoS 1,
not clean) is kept while the dashboard itself is away, so every event the gateway publishes
reaches it whenever it connects, and the test never races the gateway's reconnect.
"""

from __future__ import annotations

import asyncio
import contextlib
import signal
import sqlite3
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from gateway.config import MetricsConfig, StorageConfig
from gateway.store import EventType
from tests.support import free_port, running_gateway
from tests.support.http import Scrape, http_get
from tests.support.mosquitto import Mosquitto, MqttProbe, mqtt_probe, unique_base_topic
from tests.support.mqtt_setup import FAST_POLL, mqtt_config, simulated_line
from tests.support.processes import GatewayProcess, gateway_process

DASHBOARD = {"identifier": "dashboard", "clean_session": False}
DRIVES = [
    {"name": "pump1", "address": 1, "model": "gd350", "poll": FAST_POLL},
    {"name": "fan2", "address": 2, "model": "gd20", "poll": FAST_POLL},
    {"name": "conv3", "address": 3, "model": "gd350", "poll": FAST_POLL},
]


@contextlib.contextmanager
def persistent_broker(directory: Path) -> Iterator[Mosquitto]:
    broker = Mosquitto(directory, persistent=True)
    broker.start()
    try:
        yield broker
    finally:
        broker.stop()


async def subscribe_dashboard(broker: Mosquitto, base: str) -> None:
    """The dashboard subscribes once; the broker keeps its session (and queues for it)."""
    async with mqtt_probe(broker, f"{base}/bridge/event", **DASHBOARD):
        pass


def gateway_file_config(
    line_path: str, broker: Mosquitto, base: str, store: Path
) -> dict[str, Any]:
    return {
        "gateway_id": "sf",
        "modbus_tcp": {"host": "127.0.0.1", "port": 0},
        "buses": [
            {
                "name": "line1",
                "port": line_path,
                "baudrate": 115200,
                "parity": "E",
                "timeout_ms": 200,
                "retries": 1,
            }
        ],
        "drives": [{"bus": "line1", **d} for d in DRIVES],
        "mqtt": {
            "host": broker.host,
            "port": broker.port,
            "base_topic": base,
            "reconnect_max_s": 1.0,
            "homeassistant_discovery": False,
        },
        "storage": {"path": str(store)},
    }


def stored_events(store: Path) -> int:
    """What an operator's `sqlite3 events.db 'select count(*) from events'` says (read-only)."""
    with contextlib.closing(sqlite3.connect(f"file:{store}?mode=ro", uri=True)) as db:
        count: int = db.execute("SELECT count(*) FROM events").fetchone()[0]
        return count


def wait_stored(store: Path, count: int, timeout_s: float = 10.0) -> None:
    # Another process's file: nothing to await but the file itself.
    deadline = time.monotonic() + timeout_s
    while stored_events(store) < count:
        assert time.monotonic() < deadline, f"{stored_events(store)} of {count} events stored"
        time.sleep(0.05)  # polled with a deadline (see above)


def raise_and_clear(gateway: GatewayProcess, line: Any, pairs: dict[int, int]) -> None:
    """Fault codes 1, 2, ... raised and cleared on each drive address, `pairs[address]` times,
    each change seen by the gateway's poll before the next."""
    names = {d["address"]: d["name"] for d in DRIVES}
    for step in range(max(pairs.values())):
        for change, text in (("raise", "fault raised"), ("clear", "fault cleared")):
            busy = [address for address, count in pairs.items() if step < count]
            for address in busy:
                if change == "raise":
                    line.inject_fault(address, step + 1)
                else:
                    line.clear_fault(address)
            for address in busy:
                gateway.log.wait_for_count(f"drive {names[address]}: {text}", step + 1)


async def received_events(probe: MqttProbe, topic: str, count: int) -> list[dict[str, Any]]:
    for n in range(count):
        await probe.wait_for(topic, lambda e, n=n: len(probe.on(topic)) > n, timeout_s=15)
    return [m.json() for m in probe.on(topic)]


async def test_a_hundred_events_survive_the_outage_and_a_sigkill(tmp_path: Path) -> None:
    base = unique_base_topic()
    store = tmp_path / "state" / "events.db"
    with persistent_broker(tmp_path) as broker, simulated_line((1, 2, 3)) as line:
        await subscribe_dashboard(broker, base)
        broker.stop(graceful=True)  # the broker goes down before the faults come
        config = gateway_file_config(line.path, broker, base, store)
        with gateway_process(config, tmp_path) as gateway:
            gateway.wait_ready()
            # 17 + 17 + 16 faults, each raised and cleared: 100 events.
            await asyncio.to_thread(raise_and_clear, gateway, line, {1: 17, 2: 17, 3: 16})
            wait_stored(store, 100)
            gateway.signal(signal.SIGKILL)  # a power cut, a watchdog: no shutdown at all
            assert gateway.wait(5) == -signal.SIGKILL
        with gateway_process(config, tmp_path) as gateway:
            gateway.wait_ready()
            assert "100 events wait for the broker" in gateway.log.text
            broker.start()
            topic = f"{base}/bridge/event"
            async with mqtt_probe(broker, topic, **DASHBOARD) as probe:
                events = await received_events(probe, topic, 100)
    ids = [e["id"] for e in events]
    assert ids == list(range(1, 101)), ids  # all, in order; none twice (none was in flight)
    for drive, codes in (("pump1", 17), ("fan2", 17), ("conv3", 16)):
        mine = [e for e in events if e["data"]["drive"] == drive]
        assert [(e["type"], e["data"]["fault_code"]) for e in mine] == [
            (kind, code)
            for code in range(1, codes + 1)
            for kind in (EventType.FAULT_RAISED, EventType.FAULT_CLEARED)
        ]
    times = [e["time"] for e in events]
    assert times == sorted(times)  # the time each happened, not the time it was sent
    assert all(e["time"] == e["data"]["time"] for e in events)


async def test_an_outage_longer_than_the_store_keeps_the_newest(tmp_path: Path) -> None:
    base = unique_base_topic()
    store = tmp_path / "events.db"
    bound = int(0.1 * 1024 * 1024)
    with persistent_broker(tmp_path) as broker, simulated_line() as line:
        await subscribe_dashboard(broker, base)
        broker.stop(graceful=True)
        config = mqtt_config(line.path, broker, base, homeassistant_discovery=False)
        metrics_port = free_port()
        config = config.model_copy(
            update={
                "storage": StorageConfig(path=str(store), max_mb=0.1),
                "metrics": MetricsConfig(enabled=True, host="127.0.0.1", port=metrics_port),
            }
        )
        async with running_gateway(config) as app:
            # As the poller, the buses and the commands would record them, only faster.
            for n in range(3000):
                app.events.record(EventType.COMMAND, {"drive": "pump1", "n": n, "pad": "x" * 40})
            await app.events.flush()
            _, _, text = await http_get(metrics_port, "/metrics")
            dropped = Scrape(text)("store_events_dropped_total")
            assert Scrape(text)("store_events_undelivered") == 3000 - dropped
            assert await app.events.size_bytes() <= bound
            broker.start()
            topic = f"{base}/bridge/event"
            async with mqtt_probe(broker, topic, **DASHBOARD) as probe:
                await probe.wait_for(topic, lambda e: e["data"].get("n") == 2999, timeout_s=15)
                events = [m.json() for m in probe.on(topic)]
        assert store.stat().st_size <= bound
    kept = [e for e in events if e["type"] == "command"]
    assert 0 < len(kept) < 3000
    assert dropped == 3000 - len(kept)
    assert [e["data"]["n"] for e in kept] == list(range(3000 - len(kept), 3000))
    assert [e["id"] for e in kept] == sorted(e["id"] for e in kept)
