"""Other Modbus devices on the line: a meter described by a device file, played by pymodbus's
own RTU server (an independent peer) on a pty, published over a real Mosquitto. Every value the
gateway publishes is the one the server holds (`tests/peers/pymodbus_meter.py` lays its
registers out by hand), and a write to a writable point lands in the server."""

from __future__ import annotations

import asyncio
import json
import struct
from collections.abc import AsyncIterator, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from gateway.app import Application
from tests.peers.pymodbus_meter import EXPECTED
from tests.support import TcpClient, eventually, running_gateway
from tests.support.mosquitto import Mosquitto, MqttProbe, mqtt_probe, unique_base_topic
from tests.support.mqtt_setup import mqtt_config
from tests.support.processes import pymodbus_peer, run_cli

ROOT = Path(__file__).resolve().parent.parent
METER_FILE = ROOT / "tests" / "fixtures" / "devices" / "test_meter.yaml"
UNIT = 7


@pytest.fixture
def meter_line() -> Iterator[str]:
    """The meter at the far end of a pty cable; yields the device path the gateway opens."""
    with pymodbus_peer("pymodbus_meter", "19200", str(UNIT)) as gateway_end:
        yield gateway_end


@dataclass
class Plant:
    base: str
    app: Application
    probe: MqttProbe
    tcp: TcpClient

    async def set(self, payload: dict[str, object]) -> dict[str, Any]:
        response: dict[str, Any] = await self.probe.request(
            f"{self.base}/meter1/set", payload, f"{self.base}/meter1/set/response"
        )
        return response

    async def state(self, key: str, value: object) -> dict[str, Any]:
        received = await self.probe.wait_for(f"{self.base}/meter1", lambda s: s[key] == value)
        state: dict[str, Any] = received.json()
        return state


@pytest.fixture
async def plant(mosquitto: Mosquitto, meter_line: str) -> AsyncIterator[Plant]:
    base = unique_base_topic()
    drives = [{"name": "meter1", "address": UNIT, "model": f"file:{METER_FILE}"}]
    line = {"baudrate": 19200, "parity": "N", "timeout_ms": 500}
    config = mqtt_config(meter_line, mosquitto, base, drives=drives, bus=line)
    async with (
        mqtt_probe(mosquitto, f"{base}/#", "homeassistant/#") as probe,
        running_gateway(config) as app,
    ):
        await probe.wait_for(f"{base}/meter1/availability", lambda a: a["state"] == "online")
        tcp = await TcpClient.connect(app.tcp.port)
        try:
            yield Plant(base, app, probe, tcp)
        finally:
            await tcp.close()


async def test_every_published_value_is_what_the_meter_holds(plant: Plant) -> None:
    received = await plant.probe.wait_for(f"{plant.base}/meter1", lambda s: set(EXPECTED) <= set(s))
    state = received.json()
    assert {key: state[key] for key in EXPECTED} == {
        **EXPECTED,
        "temperature": pytest.approx(-12.5),
    }
    assert isinstance(state["energy_wh"], int)  # a u64 beyond a float's 53 bits, exact


async def test_a_write_to_a_writable_point_lands_in_the_meter(plant: Plant) -> None:
    response = await plant.set({"point": "setpoint", "value": 231.25})
    assert response["status"] == "ok", response
    # Read back from the meter itself (no poll cache on this drive): f32 ABCD in 0-1.
    words = await plant.tcp.read(UNIT, 0, 2)
    assert struct.unpack(">f", struct.pack(">2H", *words)) == (231.25,)
    await plant.state("setpoint", 231.25)

    response = await plant.set({"point": "temperature", "value": -3.5})
    assert response["status"] == "ok", response
    assert await plant.tcp.read(UNIT, 30, 1) == [(-35) & 0xFFFF]
    await plant.state("temperature", -3.5)


async def test_a_point_that_is_not_writable_is_refused_by_name(plant: Plant) -> None:
    response = await plant.set({"point": "frequency", "value": 50})
    assert (response["status"], response["error"]) == ("error", "invalid_request")
    assert "frequency of test meter is not writable" in response["message"]
    response = await plant.set({"point": "setpoint", "value": "high"})
    assert (response["error"], response["message"]) == (
        "invalid_value",
        "setpoint must be a number",
    )
    words = await plant.tcp.read(UNIT, 2, 2)
    assert struct.unpack(">f", struct.pack(">2H", words[1], words[0])) == (49.75,)  # untouched


async def test_home_assistant_sees_each_point_with_its_unit_and_class(plant: Plant) -> None:
    topic = "homeassistant/sensor/invt_test/meter1_energy_wh/config"
    config = (await plant.probe.wait_for(topic)).json()
    assert (config["unit_of_measurement"], config["device_class"]) == ("Wh", "energy")
    assert config["state_class"] == "total_increasing"
    assert config["state_topic"] == f"{plant.base}/meter1"
    number = "homeassistant/number/invt_test/meter1_setpoint/config"
    setpoint = (await plant.probe.wait_for(number)).json()
    template = setpoint["command_template"].replace("{{ value }}", "231.25")
    assert json.loads(template) == {"point": "setpoint", "value": 231.25}


async def test_pass_through_still_serves_the_meter(plant: Plant) -> None:
    # SCADA's own reads of every table go through untouched (input register 0-1: flow, BADC).
    reply = await plant.tcp.request(UNIT, bytes.fromhex("04 00 00 00 02"))
    flow = struct.unpack(">f", bytes([reply[3], reply[2], reply[5], reply[4]]))
    assert flow == (12.25,)
    await eventually(lambda: plant.app.poller.polls > 4)


def test_check_config_names_a_device_files_mistake_by_file_and_point(tmp_path: Path) -> None:
    device = tmp_path / "mymeter.yaml"
    device.write_text(
        "name: my meter\nsource: its manual\npoints:\n"
        "  flow: {table: input, address: 0, type: f32}\n"
        "  level: {table: input, address: 1}\n"
    )
    config = tmp_path / "gateway.yaml"
    config.write_text(
        "buses: [{name: line1, port: /dev/null, baudrate: 9600}]\n"
        "drives:\n"
        "  - {name: meter1, bus: line1, address: 3, model: sdm630}\n"
        f"  - {{name: boiler, bus: line1, address: 4, model: 'file:{device}'}}\n"
    )
    result = run_cli("check-config", "--config", str(config))
    assert result.returncode == 3, result.stdout + result.stderr
    assert (
        f"drives[1] (boiler).model: {device}: points.level: overlaps points.flow "
        "at input register 0001H"
    ) in result.stderr
    device.write_text(device.read_text().replace("address: 1}", "address: 2}"))
    result = run_cli("check-config", "--config", str(config))
    assert result.returncode == 0, result.stderr
    assert "sdm630" in result.stdout


async def test_a_change_within_the_deadband_is_not_published(plant: Plant) -> None:
    topic = f"{plant.base}/meter1"
    await plant.state("setpoint", 230.5)
    mark, polls = len(plant.probe.messages), plant.app.poller.polls
    assert (await plant.set({"point": "setpoint", "value": 230.75}))["status"] == "ok"
    await asyncio.sleep(1.0)  # five polls at 200 ms
    assert plant.app.poller.polls >= polls + 5
    published = [m.json().get("setpoint") for m in plant.probe.messages[mark:] if m.topic == topic]
    assert 230.75 not in published  # within its deadband of 0.5 V
    words = await plant.tcp.read(UNIT, 0, 2)
    assert struct.unpack(">f", struct.pack(">2H", *words)) == (230.75,)  # yet it is written

    assert (await plant.set({"point": "setpoint", "value": 231.5}))["status"] == "ok"
    await plant.state("setpoint", 231.5)  # 0.75 V from 230.5 published: beyond the deadband


async def test_a_point_beyond_its_limit_raises_an_alarm_and_clears_it(plant: Plant) -> None:
    events = f"{plant.base}/bridge/event"
    mark = len(plant.probe.messages)
    assert (await plant.set({"point": "temperature", "value": 5.0}))["status"] == "ok"
    raised = await plant.probe.wait_for(events, lambda e: e["type"] == "alarm_raised", after=mark)
    assert raised.json()["data"] | {"time": None} == {
        "drive": "meter1",
        "point": "temperature",
        "limit": "high",
        "value": 5.0,
        "threshold": 0.0,
        "time": None,
    }
    # Back below 0 °C but within the hysteresis of 1 °C: still raised; below -1 °C: cleared.
    mark = len(plant.probe.messages)
    assert (await plant.set({"point": "temperature", "value": -0.5}))["status"] == "ok"
    assert (await plant.set({"point": "temperature", "value": -1.5}))["status"] == "ok"
    cleared = await plant.probe.wait_for(events, lambda e: e["type"] == "alarm_cleared", after=mark)
    assert cleared.json()["data"]["value"] == -1.5
    types = [m.json()["type"] for m in plant.probe.messages[mark:] if m.topic == events]
    assert types.count("alarm_cleared") == 1


def test_check_config_warns_of_a_line_its_polls_would_fill(tmp_path: Path) -> None:
    config = tmp_path / "gateway.yaml"
    config.write_text(
        "buses: [{name: line1, port: /dev/null, baudrate: 1200}]\n"
        "mqtt: {host: 127.0.0.1}\n"
        "drives:\n"
        "  - {name: meter1, bus: line1, address: 3, model: sdm630}\n"
        "  - {name: meter2, bus: line1, address: 4, model: sdm630}\n"
    )
    result = run_cli("check-config", "--config", str(config))
    assert result.returncode == 0, result.stderr
    assert "line1: 2 polled" in result.stdout
    assert "buses[0] (line1): its polls alone need 1" in result.stderr  # more than 100 %
    config.write_text(config.read_text().replace("1200", "19200"))
    result = run_cli("check-config", "--config", str(config))
    assert "polls alone" not in result.stderr


async def test_a_writable_coil_is_switched(plant: Plant) -> None:
    response = await plant.set({"point": "valve_open", "value": True})
    assert response["status"] == "ok", response
    assert await plant.tcp.request(UNIT, bytes.fromhex("01 00 00 00 02")) == bytes.fromhex(
        "01 01 03"
    )  # coils 0 and 1 on
    await plant.state("valve_open", True)
    response = await plant.set({"point": "valve_open", "value": 1})
    assert (response["error"], response["message"]) == (
        "invalid_value",
        "valve_open is on or off: give true or false",
    )
    topic = "homeassistant/switch/invt_test/meter1_valve_open/config"
    switch = (await plant.probe.wait_for(topic)).json()
    assert json.loads(switch["payload_on"]) == {"point": "valve_open", "value": True}
