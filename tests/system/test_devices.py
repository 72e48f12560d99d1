"""Other Modbus devices on the line: a meter described by a device file, played by pymodbus's
own RTU server (an independent peer) on a pty, published over a real Mosquitto. Every value the
gateway publishes is the one the server holds (`tests/peers/pymodbus_meter.py` lays its
registers out by hand), and a write to a writable point lands in the server."""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import struct
from collections.abc import AsyncIterator, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from gateway.app import Application
from gateway.config import GatewayConfig
from tests.peers.pymodbus_meter import EXPECTED
from tests.support import TcpClient, eventually, present, running_gateway
from tests.support.console_support import OPERATOR_TOKEN, console_config
from tests.support.mosquitto import Mosquitto, MqttProbe, mqtt_probe, unique_base_topic
from tests.support.mqtt_setup import mqtt_config
from tests.support.processes import entry_point, gateway_process, pymodbus_peer, run_cli
from tests.system.test_console_monitor import line_with

ROOT = Path(__file__).resolve().parents[2]
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

    async def state(self, key: str, value: object, after: int = 0) -> dict[str, Any]:
        """The first state published from message `after` on whose `key` is `value`."""
        received = await self.probe.wait_for(
            f"{self.base}/meter1", lambda s: s.get(key) == value, after=after
        )
        state: dict[str, Any] = received.json()
        return state


@contextlib.asynccontextmanager
async def meter_plant(mosquitto: Mosquitto, meter_line: str, **mqtt: Any) -> AsyncIterator[Plant]:
    """The gateway with the meter on its line, MQTT settings `mqtt` over the tests' own."""
    base = unique_base_topic()
    drives = [{"name": "meter1", "address": UNIT, "model": f"file:{METER_FILE}"}]
    line = {"baudrate": 19200, "parity": "N", "timeout_ms": 500}
    config = mqtt_config(meter_line, mosquitto, base, drives=drives, bus=line, **mqtt)
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


@pytest.fixture
async def plant(mosquitto: Mosquitto, meter_line: str) -> AsyncIterator[Plant]:
    async with meter_plant(mosquitto, meter_line) as plant:
        yield plant


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
    config.write_text(config.read_text().replace("1200", "2400"))
    result = run_cli("check-config", "--config", str(config))
    assert "polls alone" not in result.stderr
    # 81 %: the polls fit, but past the budget that leaves the line room for SCADA.
    assert "line1: 2 polled, 2.0 requests/s, 81.0% of the line" in result.stdout
    assert "    meter1: 1.0 requests/s, 40.5%" in result.stdout
    assert "buses[0] (line1): its polls take 81% of the line, more than 70%" in result.stderr
    config.write_text(config.read_text().replace("2400", "19200"))
    result = run_cli("check-config", "--config", str(config))
    assert "warning" not in result.stderr


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


async def test_a_devices_limit_alarm_is_a_problem_binary_sensor_on_its_flag(plant: Plant) -> None:
    topic = "homeassistant/binary_sensor/invt_test/meter1_temperature_high_alarm/config"
    sensor = (await plant.probe.wait_for(topic)).json()
    assert (sensor["device_class"], sensor["state_topic"]) == ("problem", f"{plant.base}/meter1")
    assert sensor["unique_id"] == "invt_test_meter1_temperature_high_alarm"
    assert sensor["availability"][1]["topic"] == f"{plant.base}/meter1/availability"
    template = sensor["value_template"]
    assert template == "{{ 'ON' if value_json.temperature_high_alarm else 'OFF' }}"

    state = await plant.state("temperature", -12.5)
    assert state["temperature_high_alarm"] is False
    assert (await plant.set({"point": "temperature", "value": 5.0}))["status"] == "ok"
    state = await plant.state("temperature_high_alarm", True)
    assert state["temperature"] == 5.0
    # Back inside by more than the hysteresis (1 °C): the flag goes off with the value.
    mark = len(plant.probe.messages)
    assert (await plant.set({"point": "temperature", "value": -1.5}))["status"] == "ok"
    state = await plant.state("temperature_high_alarm", False, after=mark)
    assert state["temperature"] == -1.5


async def test_gateway_wide_device_defaults_are_taken_unless_the_device_file_says(
    mosquitto: Mosquitto, meter_line: str
) -> None:
    # mqtt.report.devices: a deadband of 2 for every device's points; the test meter's setpoint
    # has its own (0.5 V), its temperature none: 2 °C is the temperature's.
    async with meter_plant(mosquitto, meter_line, report={"devices": {"deadband": 2}}) as plant:
        topic = f"{plant.base}/meter1"
        await plant.state("temperature", -12.5)
        mark, polls = len(plant.probe.messages), plant.app.poller.polls
        assert (await plant.set({"point": "temperature", "value": -11.0}))["status"] == "ok"
        await asyncio.sleep(1.0)  # five polls at 200 ms
        assert plant.app.poller.polls >= polls + 5
        assert not [m for m in plant.probe.messages[mark:] if m.topic == topic]  # within 2 °C
        assert await plant.tcp.read(UNIT, 30, 1) == [(-110) & 0xFFFF]  # yet it is written

        mark = len(plant.probe.messages)
        assert (await plant.set({"point": "setpoint", "value": 231.25}))["status"] == "ok"
        state = await plant.state("setpoint", 231.25, after=mark)  # 0.75 V: beyond its 0.5 V
        assert state["temperature"] == -11.0  # a state is one message: it goes along

        mark = len(plant.probe.messages)
        assert (await plant.set({"point": "temperature", "value": -10.0}))["status"] == "ok"
        assert (await plant.set({"point": "temperature", "value": -8.5}))["status"] == "ok"
        await plant.state("temperature", -8.5, after=mark)  # 2.5 °C from -11: beyond 2
        published = [
            m.json()["temperature"] for m in plant.probe.messages[mark:] if m.topic == topic
        ]
        assert -10.0 not in published


def test_check_config_names_a_bad_device_default_by_its_key(tmp_path: Path) -> None:
    config = tmp_path / "gateway.yaml"
    config.write_text(
        "buses: [{name: line1, port: /dev/null, baudrate: 9600}]\n"
        "mqtt: {host: 127.0.0.1, report: {deadband: 1, devices: {deadband_percent: -5}}}\n"
        "drives: [{name: meter1, bus: line1, address: 3, model: sdm630}]\n"
    )
    result = run_cli("check-config", "--config", str(config))
    assert result.returncode == 3, result.stdout + result.stderr
    assert "mqtt.report.devices.deadband_percent" in result.stderr
    assert "greater than or equal to 0" in result.stderr


def test_a_point_named_like_another_points_alarm_flag_is_refused(tmp_path: Path) -> None:
    device = tmp_path / "boiler.yaml"
    device.write_text(
        "name: boiler\nsource: its manual\npoints:\n"
        "  water_c: {address: 0, type: s16, high: 90}\n"
        "  water_c_high_alarm: {address: 1}\n"
    )
    config = tmp_path / "gateway.yaml"
    config.write_text(
        "buses: [{name: line1, port: /dev/null, baudrate: 9600}]\n"
        f"drives: [{{name: boiler, bus: line1, address: 4, model: 'file:{device}'}}]\n"
    )
    result = run_cli("check-config", "--config", str(config))
    assert result.returncode == 3, result.stdout + result.stderr
    assert (
        f"drives[0] (boiler).model: {device}: points.water_c_high_alarm: is the state's key of "
        "points.water_c's high alarm"
    ) in result.stderr


async def test_the_traffic_monitor_shows_a_float_as_its_value(meter_line: str) -> None:
    data = console_config(meter_line).model_dump(mode="json", exclude_none=True)
    data["buses"][0].update(baudrate=19200, parity="N", timeout_ms=500)
    data["drives"] = [
        {"name": "meter1", "bus": "line1", "address": UNIT, "model": f"file:{METER_FILE}"}
    ]
    async with running_gateway(GatewayConfig.model_validate(data)) as app:
        url = f"http://127.0.0.1:{present(app.console).port}"
        process = await asyncio.create_subprocess_exec(
            *(entry_point(), "monitor", "--url", url, "--bus", "line1", "--recent", "0"),
            stdin=asyncio.subprocess.DEVNULL,
            stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.PIPE,
            env={**os.environ, "INVT_GATEWAY_CONSOLE_TOKEN": OPERATOR_TOKEN},
        )
        try:
            assert process.stderr is not None
            assert process.stdout is not None
            await line_with(process.stderr, "watching")
            tcp = await TcpClient.connect(app.tcp.port)
            await tcp.request(UNIT, bytes.fromhex("03 0000 0004"))  # setpoint, frequency
            await tcp.close()
            printed = await line_with(process.stdout, "tcp:127.0.0.1")
            # f32 ABCD and CDAB, as MQTT publishes them: not 4366H 8000H ...
            assert "→ setpoint 230.5 V, frequency 49.75 Hz  [ok," in printed
        finally:
            process.terminate()
            await asyncio.wait_for(process.wait(), 5)


async def test_a_reload_reads_an_edited_device_file_again(
    mosquitto: Mosquitto, meter_line: str, tmp_path: Path
) -> None:
    """A site's device file is its drive's definition: `invt-gateway reload` after an edit
    polls and publishes the points as the file says now, with no key of the configuration
    changed."""
    device = tmp_path / "meter.yaml"
    original = METER_FILE.read_text()
    device.write_text(original.replace("  mode: {address: 0x1D", "  # mode: {address: 0x1D"))
    base = unique_base_topic()
    config = mqtt_config(
        meter_line,
        mosquitto,
        base,
        drives=[{"name": "meter1", "address": UNIT, "model": f"file:{device}"}],
        bus={"baudrate": 19200, "parity": "N", "timeout_ms": 500},
    )
    data = config.model_dump(mode="json", exclude_none=True)
    async with mqtt_probe(mosquitto, f"{base}/#") as probe:
        with gateway_process(data, tmp_path) as gateway:
            await asyncio.to_thread(gateway.wait_ready)
            state = (await probe.wait_for(f"{base}/meter1", lambda s: "serial" in s)).json()
            assert "mode" not in state  # not in the file yet

            device.write_text(original)  # the site adds the point
            mark = len(probe.messages)
            path = str(gateway.config_file)
            result = await asyncio.to_thread(run_cli, "reload", "--config", path)
            assert result.returncode == 0, result.stderr
            assert "drives changed: meter1" in result.stdout
            received = await probe.wait_for(f"{base}/meter1", lambda s: "mode" in s, after=mark)
            assert received.json()["mode"] == "remote"  # what the meter holds at 001DH
