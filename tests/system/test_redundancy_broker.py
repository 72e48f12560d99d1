"""What the two boxes of a redundant pair tell each other through the broker (issue 48), with two
real gateway processes on one simulated line (`simulate --masters 2`) and a real Mosquitto.

What a site checks: a reload on one box that makes its configuration differ from the other's
in what both must share is named, key by key and without values, on the other box (its `role
status`, /health, console, metric, log and events) within seconds, and cleared once they are
alike again; and the events a box recorded while its broker was away, and had not delivered
when it was killed, reach the consumers once when it comes back as standby, and not again.
"""

from __future__ import annotations

import asyncio
import json
import signal
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from gateway.poller.drive_state import iso_time
from tests.support import free_port
from tests.support.http import http_get
from tests.support.mosquitto import Mosquitto, MqttProbe, mqtt_probe
from tests.support.processes import run_cli
from tests.support.redundancy import Box, pair_broker, start_pair
from tests.support.redundancy import boxes as boxes  # the fixtures
from tests.support.redundancy import line as line
from tests.support.shared_line import SharedLine

TOLD_WITHIN_S = 5.0
"""A reload on one box named on the other within this (the announcement is sent at once)."""


def peer_config(box: Box, done: Callable[[dict[str, Any]], bool], within_s: float) -> Any:
    """`role status`'s `peer_config` once `done` says so (polled: another process's state)."""
    deadline = time.monotonic() + within_s
    while True:
        shown = box.status().get("peer_config")
        if shown is not None and done(shown):
            return shown
        assert time.monotonic() < deadline, f"box {box.name}: peer_config {shown}"
        time.sleep(0.1)


def alike(host: str, broker: dict[str, Any], ports: tuple[int, int], **more: Any) -> Any:
    """A box's sections besides the line's, alike on both boxes but for `host`: the MQTT
    broker, /metrics and the console on `ports`."""
    metrics, console = ports
    return {
        "mqtt": broker,
        "metrics": {"enabled": True, "host": host, "port": metrics},
        "console": {"enabled": True, "host": host, "port": console, "anonymous_view": True},
        **more,
    }


def alike_pair(broker: dict[str, Any]) -> tuple[tuple[int, int], Any, Any]:
    """One file on both boxes but for each box's own keys: the same ports, each box's address
    (two loopback addresses here, as two boxes' on a plant network). (The ports, box a's
    sections, box b's.)"""
    ports = (free_port(), free_port())
    return ports, alike("127.0.0.1", broker, ports), alike("127.0.0.2", broker, ports)


def edit(box: Box, old: str, new: str) -> None:
    path = Path(box.config)
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new))


def test_a_reload_on_one_box_is_told_on_the_other_and_cleared_once_alike(
    line: SharedLine, boxes: list[Box], tmp_path: Path, mosquitto: Mosquitto
) -> None:
    _, events, broker = pair_broker(mosquitto)
    ports, a, b = alike_pair(broker)
    active, standby = start_pair(boxes, line.paths, tmp_path, a=a, b=b)
    # Alike at start: each box has heard the other's configuration and says so.
    for box in (active, standby):
        assert peer_config(box, lambda p: p["differs"] == [], TOLD_WITHIN_S)["peer"] != box.name

    async def reload_told() -> list[Any]:
        async with mqtt_probe(mosquitto, events) as probe:
            edit(active, "timeout_ms: 100", "timeout_ms: 120")
            applied = await asyncio.to_thread(run_cli, "reload", "--config", active.config)
            assert applied.returncode == 0, applied.stderr
            started = time.monotonic()
            shown = await asyncio.to_thread(
                peer_config, standby, lambda p: p["differs"] != [], TOLD_WITHIN_S
            )
            print(f"told on the standby {time.monotonic() - started:.2f} s after the reload")
            # Each box records it; the standby's goes out on its role connection.
            told = await probe.wait_for(
                events, lambda e: e["type"] == "peer_config_differs" and e["box"] == "b"
            )
            return [shown, told.json()]

    shown, told = asyncio.run(reload_told())
    assert shown["differs"] == ["buses[line1].timeout_ms"]
    assert (shown["peer"], shown["count"]) == ("a", 1)
    assert told["data"] == {"peer": "a", "count": 1, "keys": ["buses[line1].timeout_ms"]}
    # Said on every side the operator looks at, the key and never its value.
    warning = standby.gateway.log.wait_for("configuration box a runs differs")
    said = warning.split("runs differs")[1]
    assert "buses[line1].timeout_ms" in said
    assert "120" not in said
    assert standby.health()["redundancy"]["peer_config"]["differs"] == ["buses[line1].timeout_ms"]
    assert "invt_gateway_redundancy_peer_config_differences 1.0" in standby.metrics()
    _, _, body = asyncio.run(http_get(ports[1], "/api/overview", "127.0.0.2"))
    assert json.loads(body)["redundancy"]["peer_config"]["differs"] == ["buses[line1].timeout_ms"]
    # The active box says the same of the standby's.
    assert peer_config(active, lambda p: p["count"] == 1, 1.0)["peer"] == "b"

    # The standby's file edited alike and reloaded: skipped (a standby applies its file at its
    # restart), so it still runs the old one, and the boxes still differ: the box that would
    # take over would run it.
    edit(standby, "timeout_ms: 100", "timeout_ms: 120")
    skipped = run_cli("reload", "--config", standby.config)
    assert "skipped: this gateway is standby" in skipped.stderr
    time.sleep(0.5)
    assert standby.status()["peer_config"]["count"] == 1
    # Its restart with the new file: announced, and both boxes alike again.
    standby.stop()
    bus = {"name": "line1", "port": line.paths[1], "timeout_ms": 120, "retries": 1}
    restarted = alike("127.0.0.2", broker, ports, buses=[bus])
    boxes[1] = standby = Box("b", line.paths[1], tmp_path, "standby", **restarted)
    for box in (active, standby):
        assert peer_config(box, lambda p: p["differs"] == [], TOLD_WITHIN_S)["count"] == 0
    active.gateway.log.wait_for("box b runs this box's configuration again")
    assert "invt_gateway_redundancy_peer_config_differences 0.0" in active.metrics()
    assert line.stats()["masters"][1]["frames"] == 0
    assert line.stats()["collisions"] == 0


def fault_events(probe: MqttProbe, topic: str, box: str, code: int) -> list[dict[str, Any]]:
    found = [m.json() for m in probe.on(topic)]
    return [
        event
        for event in found
        if event["type"] == "fault_raised"
        and event.get("box") == box
        and event["data"]["fault_code"] == code
    ]


async def test_events_recorded_while_the_broker_was_away_are_handed_over_once_by_the_old_active(
    line: SharedLine, boxes: list[Box], tmp_path: Path, mosquitto: Mosquitto
) -> None:
    base, events, broker = pair_broker(mosquitto)
    _, a, b = alike_pair(broker)
    old, new = await asyncio.to_thread(start_pair, boxes, line.paths, tmp_path, a=a, b=b)
    async with mqtt_probe(mosquitto, f"{base}/pump") as probe:
        await probe.wait_for(f"{base}/pump", lambda s: s["fault_code"] == 0)

    # The broker away: box a records the drive's trip and can't deliver it; then it dies.
    mosquitto.stop()
    line.command("fault 1 35")
    await asyncio.to_thread(old.gateway.log.wait_for, "fault raised")
    await asyncio.sleep(0.3)  # written to its store (the writer's next step)
    old.gateway.process.send_signal(signal.SIGKILL)
    await asyncio.to_thread(old.gateway.process.wait, 5)
    killed = iso_time(time.time())
    mosquitto.start()

    async with mqtt_probe(mosquitto, events) as probe:
        await asyncio.to_thread(new.notified, "MASTER")
        await asyncio.to_thread(new.wait_role, "active", 5.0)
        # The new active was never told of the trip: it reports it itself, from its own polls.
        await probe.wait_for(events, lambda e: e.get("box") == "b" and "fault_code" in e["data"])
        # Box a back, as standby: its backlog goes out on its role connection, each event
        # once, with its own box and time (before the kill: when it happened).
        await asyncio.to_thread(old.stop)
        boxes[0] = old = await asyncio.to_thread(Box, "a", line.paths[0], tmp_path, "standby", **a)
        handed = await probe.wait_for(
            events, lambda e: e.get("box") == "a" and e["type"] == "fault_raised", 15.0
        )
        assert handed.json()["time"] < killed
        await asyncio.sleep(1.5)
        assert len(fault_events(probe, events, "a", 35)) == 1
        # Delivered is marked in its store: another restart sends it no more.
        await asyncio.to_thread(old.stop)
        boxes[0] = old = await asyncio.to_thread(Box, "a", line.paths[0], tmp_path, "standby", **a)
        await asyncio.sleep(2.0)
        assert len(fault_events(probe, events, "a", 35)) == 1
        ids = [(m.json().get("box"), m.json()["id"]) for m in probe.on(events)]
        assert len(ids) == len(set(ids)), ids  # nothing told twice
    assert old.status()["role"] == "standby"
    assert line.stats()["collisions"] == 0
