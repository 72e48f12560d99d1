"""Scale-out: two gateway processes, each with its own line, on one broker. Each keeps to its own
topic tree and Home Assistant ids, and each one's last will tells only about itself: one
gateway dying (SIGKILL: no goodbye) leaves the other online."""

from __future__ import annotations

import asyncio
import signal
from pathlib import Path
from typing import Any

from tests.support import free_port
from tests.support.mosquitto import Mosquitto, MqttProbe, mqtt_probe, unique_base_topic
from tests.support.mqtt_setup import FAST_POLL, simulated_line
from tests.support.processes import gateway_process

OFFLINE = {"state": "offline"}


def gateway(
    gateway_id: str, line: str, broker: Mosquitto, base: str, prefix: str
) -> dict[str, Any]:
    return {
        "gateway_id": gateway_id,
        "modbus_tcp": {"host": "127.0.0.1", "port": free_port()},
        "buses": [{"name": "line1", "port": line, "baudrate": 115200}],
        # The same drive names on both: the topic bases keep them apart.
        "drives": [
            {"name": "pump1", "bus": "line1", "address": 1, "model": "gd350", "poll": FAST_POLL},
        ],
        "mqtt": {
            "host": broker.host,
            "port": broker.port,
            "base_topic": base,
            "discovery_prefix": prefix,
            "reconnect_max_s": 1.0,
            "publish_interval_s": 0.5,
        },
    }


def discovery_ids(probe: MqttProbe, prefix: str) -> dict[str, str]:
    """unique_id -> the state topic it was announced for."""
    ids = {}
    for message in probe.messages:
        if message.topic.startswith(f"{prefix}/") and message.payload:
            entity = message.json()
            ids[entity["unique_id"]] = entity.get("state_topic", entity.get("command_topic", ""))
    return ids


async def test_two_gateways_share_one_broker(mosquitto: Mosquitto, tmp_path: Path) -> None:
    site = unique_base_topic("site")
    base_a, base_b = f"{site}/cabinet-a", f"{site}/cabinet-b"
    prefix = unique_base_topic("ha")
    with simulated_line((1,)) as line_a, simulated_line((1,)) as line_b:
        config_a = gateway("cabinet-a", line_a.path, mosquitto, base_a, prefix)
        config_b = gateway("cabinet-b", line_b.path, mosquitto, base_b, prefix)
        async with mqtt_probe(mosquitto, f"{site}/#", f"{prefix}/#") as probe:
            with (
                gateway_process(config_a, tmp_path) as first,
                gateway_process(config_b, tmp_path) as second,
            ):
                await asyncio.to_thread(first.wait_ready)
                await asyncio.to_thread(second.wait_ready)
                for base in (base_a, base_b):
                    await probe.wait_for(f"{base}/bridge/state", lambda s: s["state"] == "online")
                    await probe.wait_for(f"{base}/pump1", lambda s: s.get("state") == "stopped")
                # A dashboard that subscribes later sees both, retained.
                async with mqtt_probe(mosquitto, f"{site}/+/bridge/state") as late:
                    for base in (base_a, base_b):
                        state = await late.wait_for(f"{base}/bridge/state")
                        assert state.retain
                        assert state.json()["state"] == "online"

                # Home Assistant sees two devices, with no id claimed twice.
                await asyncio.sleep(0.3)  # asserting an absence: time for a duplicate to arrive
                ids = discovery_ids(probe, prefix)
                ids_a = {i for i, topic in ids.items() if topic.startswith(f"{base_a}/")}
                ids_b = {i for i, topic in ids.items() if topic.startswith(f"{base_b}/")}
                assert ids_a
                assert ids_b
                assert not ids_a & ids_b

                # Cabinet A dies without a word: the broker publishes its last will, for A only.
                mark = len(probe.messages)
                first.signal(signal.SIGKILL)
                await probe.wait_for(f"{base_a}/bridge/state", lambda s: s == OFFLINE, after=mark)
                await asyncio.sleep(0.3)  # asserting an absence: no last will for B
                assert not [
                    m
                    for m in probe.messages[mark:]
                    if m.topic == f"{base_b}/bridge/state" and m.json() == OFFLINE
                ]
                await probe.wait_for(f"{base_b}/pump1", after=mark)  # B still publishes
                async with mqtt_probe(mosquitto, f"{base_b}/bridge/state") as late:
                    assert (await late.wait_for(f"{base_b}/bridge/state")).json()[
                        "state"
                    ] == "online"

                # Cabinet B stops cleanly: it says offline itself, and exits 0.
                mark = len(probe.messages)
                second.signal(signal.SIGTERM)
                await probe.wait_for(f"{base_b}/bridge/state", lambda s: s == OFFLINE, after=mark)
                assert await asyncio.to_thread(second.wait, 2.0) == 0
