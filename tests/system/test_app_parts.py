"""Every combination of the optional sections starts, serves and stops cleanly.

The application builds each optional part (the MQTT bridge, with or without its Sparkplug B
edge node; the console; /metrics with /health) only when its section is there, and the poller
whatever the drives: none of them may lean on another being present. A configuration with
`mqtt:` and `drives: []` passed `check-config` and then `run` died (`'Application' object has
no attribute 'poller'`); these tests start each combination and check that every part it names
answers, that no other part is there, and that it stops within 2 s with nothing logged as an
error.

In-process for the whole product of the sections (24 cases, a fraction of a second each), and as
a real `invt-gateway run` for the combinations people write (a subprocess each). The broker
remembers the gateway's last run (its retained `bridge/state` "offline" and its Home Assistant
connection entity), as it does for every restart after the first: the start-up check that no
other gateway is live then has its answer at once instead of waiting a second for silence.
"""

from __future__ import annotations

import asyncio
import itertools
import logging
import signal
import time
from pathlib import Path
from typing import Any

import pytest

from gateway.config import GatewayConfig
from gateway.instruments.simulator import SimulatedLine
from gateway.mqtt.alone import gateway_entity_topic
from tests.support import TcpClient, free_port, read_pdu, running_gateway
from tests.support.console_support import USERS
from tests.support.http import http_get
from tests.support.mosquitto import Mosquitto, mqtt_probe, unique_base_topic
from tests.support.processes import gateway_process

STOPS_WITHIN_S = 2.0
GATEWAY_ID = "parts"
STATE_WORD_1 = 0x2100

DRIVES = ("none", "two")
MQTT = ("off", "json", "json+sparkplug")
ONOFF = ("off", "on")


def configuration(
    line: SimulatedLine,
    broker: Mosquitto | None,
    base_topic: str,
    *,
    drives: str,
    mqtt: str,
    console: str,
    metrics: str,
) -> dict[str, Any]:
    """The YAML a person would write for this combination, as a dict."""
    config: dict[str, Any] = {
        "gateway_id": GATEWAY_ID,
        "modbus_tcp": {"host": "127.0.0.1", "port": free_port()},
        "buses": [{"name": "line1", "port": line.path, "baudrate": 115200, "parity": "E"}],
        "drives": (
            []
            if drives == "none"
            else [
                {"name": "pump1", "bus": "line1", "address": 1},
                {"name": "fan2", "bus": "line1", "address": 2},
            ]
        ),
    }
    if mqtt != "off":
        assert broker is not None
        config["mqtt"] = {
            "host": broker.host,
            "port": broker.port,
            "base_topic": base_topic,
            "reconnect_max_s": 1.0,
        }
        if mqtt == "json+sparkplug":
            config["mqtt"]["sparkplug"] = {"group_id": "parts", "edge_node_id": base_topic}
    if console == "on":
        config["console"] = {
            "enabled": True,
            "host": "127.0.0.1",
            "port": free_port(),
            "users": USERS,
        }
    if metrics == "on":
        config["metrics"] = {"enabled": True, "host": "127.0.0.1", "port": free_port()}
    return config


async def remembers_last_run(broker: Mosquitto, base_topic: str) -> None:
    """What the gateway's previous run left retained on the broker: its bridge offline, and
    its connection entity pointing at that bridge state."""
    state = f"{base_topic}/bridge/state"
    last_run = {
        "state": "offline",
        "gateway_id": GATEWAY_ID,
        "client_id": f"invt-gateway-{GATEWAY_ID}",
    }
    entity = {"state_topic": state}
    async with mqtt_probe(broker) as probe:
        await probe.publish(state, last_run, retain=True)
        await probe.publish(gateway_entity_topic("homeassistant", GATEWAY_ID), entity, retain=True)


async def assert_modbus_tcp_answers(port: int, drives: str) -> None:
    """A read of pump1's state word: the drive's answer, or 0AH where no drive is configured."""
    client = await TcpClient.connect(port)
    try:
        reply = await client.request(1, read_pdu(STATE_WORD_1))
    finally:
        await client.close()
    expected = bytes((3, 2)) if drives == "two" else bytes.fromhex("83 0a")
    assert reply[:2] == expected, reply.hex(" ")


COMBINATIONS = list(itertools.product(DRIVES, MQTT, ONOFF, ONOFF))


@pytest.mark.parametrize(("drives", "mqtt", "console", "metrics"), COMBINATIONS)
async def test_each_combination_starts_serves_and_stops_in_process(
    line: SimulatedLine,
    request: pytest.FixtureRequest,
    caplog: pytest.LogCaptureFixture,
    drives: str,
    mqtt: str,
    console: str,
    metrics: str,
) -> None:
    broker: Mosquitto | None = request.getfixturevalue("mosquitto") if mqtt != "off" else None
    base = unique_base_topic("parts")
    if broker is not None:
        await remembers_last_run(broker, base)
    wanted = dict(drives=drives, mqtt=mqtt, console=console, metrics=metrics)
    config = GatewayConfig.model_validate(configuration(line, broker, base, **wanted))
    caplog.set_level(logging.WARNING)
    async with running_gateway(config) as app:
        await assert_modbus_tcp_answers(app.tcp.port, drives)
        assert (app.mqtt is None) is (mqtt == "off")
        assert (app.console is None) is (console == "off")
        assert (app.metrics is None) is (metrics == "off")
        # Without MQTT or the console, only drives that ask for polls are polled.
        polled = drives == "two" and (mqtt != "off" or console == "on")
        assert set(app.poller.drives) == ({"pump1", "fan2"} if polled else set())
        if app.mqtt is not None:
            await asyncio.wait_for(app.mqtt.connected.wait(), 5)
            node = app.sparkplug
            assert (node is None) is (mqtt == "json")
            if node is not None:
                await asyncio.wait_for(node.connected.wait(), 5)
        if app.console is not None:
            status, _, _ = await http_get(app.console.port, "/login")
            assert status == 200
        if app.metrics is not None:
            status, _, body = await http_get(app.metrics.port, "/health")
            assert status == 200, body
        stopping = time.monotonic()
    # running_gateway's exit re-raises whatever the application died of
    assert time.monotonic() - stopping < STOPS_WITHIN_S
    errors = [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]
    assert errors == []


NAMED = {
    "mqtt without drives": dict(drives="none", mqtt="json", console="off", metrics="off"),
    "console without mqtt": dict(drives="two", mqtt="off", console="on", metrics="off"),
    "metrics alone": dict(drives="none", mqtt="off", console="off", metrics="on"),
    "sparkplug beside json, no drives": dict(
        drives="none", mqtt="json+sparkplug", console="off", metrics="off"
    ),
    "mqtt and console": dict(drives="two", mqtt="json", console="on", metrics="off"),
    "none": dict(drives="none", mqtt="off", console="off", metrics="off"),
    "all": dict(drives="two", mqtt="json+sparkplug", console="on", metrics="on"),
}


@pytest.mark.parametrize("wanted", NAMED.values(), ids=NAMED.keys())
async def test_the_combinations_people_write_run_as_the_service(
    line: SimulatedLine, request: pytest.FixtureRequest, tmp_path: Path, wanted: dict[str, str]
) -> None:
    broker: Mosquitto | None = (
        request.getfixturevalue("mosquitto") if wanted["mqtt"] != "off" else None
    )
    base = unique_base_topic("parts")
    if broker is not None:
        await remembers_last_run(broker, base)
    config = configuration(line, broker, base, **wanted)
    with gateway_process(config, tmp_path) as gateway:
        await asyncio.to_thread(gateway.wait_ready)
        await assert_modbus_tcp_answers(config["modbus_tcp"]["port"], wanted["drives"])
        if broker is not None:
            async with mqtt_probe(broker, f"{base}/bridge/state") as probe:
                await probe.wait_for(f"{base}/bridge/state", lambda s: s["state"] == "online")
        if "console" in config:
            status, _, _ = await http_get(config["console"]["port"], "/login")
            assert status == 200
        if "metrics" in config:
            status, _, body = await http_get(config["metrics"]["port"], "/health")
            assert status == 200, body
        stopping = time.monotonic()
        gateway.signal(signal.SIGTERM)
        code = await asyncio.to_thread(gateway.wait, STOPS_WITHIN_S + 1)
        stopped_after = time.monotonic() - stopping
    assert code == 0, gateway.log.text
    assert stopped_after < STOPS_WITHIN_S, gateway.log.text
    for bad in (" ERROR ", " CRITICAL ", "Traceback"):
        assert bad not in gateway.log.text, gateway.log.text
