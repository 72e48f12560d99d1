"""Hard faults under load, each timed until the gateway is back: the serial adapter unplugged and
plugged in again, the broker killed and restarted, the gateway itself killed (SIGKILL) and
started again. Throughout, checked clients (`gateway.instruments.stress.checked_load`) read and
write, and no value they receive may be wrong; errors are allowed only while the outage lasts.

Each test records its recovery time (shown under "figures" after the run).
"""

from __future__ import annotations

import asyncio
import time
from pathlib import Path
from typing import Any

import pytest

from gateway.config import GatewayConfig, MqttConfig
from gateway.instruments.simulator import SimulatedLine
from gateway.instruments.stress.checked_load import STEADY, CheckedLoad
from gateway.instruments.stress.scenario import first_answer_after
from tests.support import RecordProperty, eventually, free_port, present, running_gateway
from tests.support.mosquitto import Mosquitto, unique_base_topic
from tests.support.processes import GatewayProcess

UNITS = [1, 2]
# Parity N: the port is reopened, and a pty refuses re-configuration with a parity.
pytestmark = pytest.mark.line(addresses=UNITS, parity="N", link="ttyRS485")
CLIENTS = 4
LIMIT_S = 5.0


def line_config(link: str, port: int = 0) -> dict[str, Any]:
    return {
        "gateway_id": "recovery",
        "modbus_tcp": {"host": "127.0.0.1", "port": port},
        # Parity N: the port is reopened, and a pty refuses re-configuration with a parity.
        "buses": [{"name": "line1", "port": link, "baudrate": 115200, "parity": "N"}],
        "drives": [{"name": f"drive{u}", "bus": "line1", "address": u} for u in UNITS],
    }


async def steady_for(load: CheckedLoad, seconds: float) -> None:
    answered = load.stats.answered
    await asyncio.sleep(seconds)  # the thing under test: traffic over a window
    assert load.stats.answered > answered, "no right answers while nothing was wrong"


async def test_serial_port_unplugged_and_plugged_back_in(
    line: SimulatedLine, record_property: RecordProperty
) -> None:
    config = GatewayConfig.model_validate(line_config(line.path))
    async with running_gateway(config) as app:
        # The drives were fine, the port wasn't: they are probed the moment it is back, not
        # after an offline drive's backoff (made far longer than LIMIT_S here to show it).
        app.buses["line1"].health.probe_initial_s = 60.0
        load = CheckedLoad(app.tcp.port, UNITS, CLIENTS)
        stop = asyncio.Event()
        task = asyncio.create_task(load.run(stop))
        try:
            await steady_for(load, 0.5)
            load.phase = "unplugged"
            line.unplug()
            await asyncio.sleep(1.0)  # the thing under test: the adapter stays away a second
            line.replug()  # a new pty, the link pointed at it: a re-enumerated adapter
            seconds = await first_answer_after(load, time.monotonic())
            await steady_for(load, 0.5)
        finally:
            stop.set()
            await task
        assert seconds is not None
        assert seconds < LIMIT_S
        assert app.buses["line1"].stats.reopens >= 1
    stats = load.stats
    assert stats.wrong == 0, stats.wrong_examples
    assert stats.errors["unplugged"] > 0  # the clients did notice: 0BH while it was away
    assert stats.errors[STEADY] == 0
    record_property("figure:recovery serial port", f"{seconds:.2f} s after plugged back in")


async def test_broker_killed_and_restarted_costs_modbus_nothing(
    line: SimulatedLine, mosquitto: Mosquitto, record_property: RecordProperty
) -> None:
    config = GatewayConfig.model_validate(line_config(line.path)).model_copy(
        update={
            "mqtt": MqttConfig.model_validate(
                {
                    "host": mosquitto.host,
                    "port": mosquitto.port,
                    "base_topic": unique_base_topic(),
                    "reconnect_max_s": 1.0,
                    "homeassistant_discovery": False,
                }
            )
        }
    )
    async with running_gateway(config) as app:
        await asyncio.wait_for(present(app.mqtt).connected.wait(), LIMIT_S)
        load = CheckedLoad(app.tcp.port, UNITS, CLIENTS)
        stop = asyncio.Event()
        task = asyncio.create_task(load.run(stop))
        try:
            await steady_for(load, 0.5)
            mosquitto.stop()  # SIGKILL
            await eventually(
                lambda: not present(app.mqtt).connected.is_set(), 2.0, "the broker lost"
            )
            await steady_for(load, 0.8)
            mosquitto.start()  # same port, nothing retained (no persistence)
            restarted = time.monotonic()
            await asyncio.wait_for(present(app.mqtt).connected.wait(), LIMIT_S)
            seconds = time.monotonic() - restarted
            await steady_for(load, 0.3)
        finally:
            stop.set()
            await task
    stats = load.stats
    assert stats.wrong == 0, stats.wrong_examples
    assert stats.errors[STEADY] == 0  # Modbus-TCP never noticed the broker was gone
    record_property("figure:recovery MQTT broker", f"{seconds:.2f} s after restarted")


async def test_gateway_killed_and_started_again(
    line: SimulatedLine, tmp_path: Path, record_property: RecordProperty
) -> None:
    port = free_port()
    config = line_config(line.path, port)
    first = GatewayProcess(config, tmp_path)
    second: GatewayProcess | None = None
    try:
        first.wait_ready()
        load = CheckedLoad(port, UNITS, CLIENTS)
        stop = asyncio.Event()
        task = asyncio.create_task(load.run(stop))
        try:
            await steady_for(load, 0.5)
            load.phase = "killed"
            killed = time.monotonic()
            first.process.kill()  # SIGKILL: no shutdown, the kernel releases port and socket
            await asyncio.to_thread(first.process.wait, 5)
            second = GatewayProcess(config, tmp_path)
            seconds = await first_answer_after(load, killed, new_connection=True)
            await steady_for(load, 0.5)
        finally:
            stop.set()
            await task
    finally:
        first.stop()
        if second is not None:
            second.stop()
    assert seconds is not None
    assert seconds < LIMIT_S
    stats = load.stats
    assert stats.wrong == 0, stats.wrong_examples
    assert stats.errors[STEADY] == 0
    record_property("figure:recovery gateway SIGKILL", f"{seconds:.2f} s from the kill")
