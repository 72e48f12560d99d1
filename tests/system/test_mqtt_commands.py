"""Commands in: every command kind acknowledged, the simulated drive really changed (read back
over Modbus-TCP or from the simulator), and each refusal answered with its reason."""

from __future__ import annotations

import asyncio
import time
from collections.abc import AsyncIterator
from dataclasses import dataclass
from typing import Any

import pytest

from gateway.app import Application
from gateway.instruments.simulator import SimulatedLine
from gateway.profile import parse_parameter
from gateway.profile.invt import STATE_WORD_1
from gateway.profile.states import RunState
from tests.support import TcpClient, eventually, present, running_gateway, write_pdu
from tests.support.mosquitto import (
    Mosquitto,
    MqttProbe,
    Received,
    mqtt_probe,
    unique_base_topic,
)
from tests.support.mqtt_setup import mqtt_config, simulated_line
from tests.support.service_log import lines, service_log

FREQUENCY_SETPOINT = 0x2001


@dataclass
class Plant:
    base: str
    line: SimulatedLine
    app: Application
    probe: MqttProbe
    tcp: TcpClient

    async def set(self, drive: str, payload: dict[str, object]) -> dict[str, Any]:
        response: dict[str, Any] = await self.probe.request(
            f"{self.base}/{drive}/set", payload, f"{self.base}/{drive}/set/response"
        )
        return response

    async def bridge(self, operation: str, payload: dict[str, object]) -> dict[str, Any]:
        response: dict[str, Any] = await self.probe.request(
            f"{self.base}/bridge/request/{operation}",
            payload,
            f"{self.base}/bridge/response/{operation}",
        )
        return response

    def state(self, address: int) -> RunState:
        with self.line.lock:
            return self.line.drives[address].state(time.monotonic())

    def parameter(self, address: int, name: str) -> int:
        with self.line.lock:
            return self.line.drives[address].parameter(name)


@pytest.fixture
async def plant(mosquitto: Mosquitto) -> AsyncIterator[Plant]:
    base = unique_base_topic()
    with simulated_line() as line:
        config = mqtt_config(line.path, mosquitto, base)
        async with mqtt_probe(mosquitto, f"{base}/#") as probe, running_gateway(config) as app:
            await probe.wait_for(f"{base}/pump1/availability", lambda a: a["state"] == "online")
            tcp = await TcpClient.connect(app.tcp.port)
            try:
                yield Plant(base, line, app, probe, tcp)
            finally:
                await tcp.close()


async def test_run_with_frequency_stop_and_reverse(plant: Plant) -> None:
    response = await plant.set("pump1", {"command": "run_forward", "frequency_hz": 35.0})
    assert response["status"] == "ok"
    assert response["data"] == {"command": "run_forward", "frequency_hz": 35.0}
    assert "transaction" in response
    assert await plant.tcp.read(1, STATE_WORD_1) == [RunState.RUNNING_FORWARD]
    assert await plant.tcp.read(1, FREQUENCY_SETPOINT) == [3500]
    # The published state follows: running forward, toward the new set-point.
    await plant.probe.wait_for(
        f"{plant.base}/pump1",
        lambda s: s["state"] == "running_forward" and s.get("set_frequency_hz") == 35.0,
    )

    assert (await plant.set("pump1", {"command": "stop"}))["status"] == "ok"
    await eventually(lambda: plant.state(1) is RunState.STOPPED)

    assert (await plant.set("pump1", {"command": "run_reverse"}))["status"] == "ok"
    assert plant.state(1) is RunState.RUNNING_REVERSE
    assert (await plant.set("pump1", {"command": "coast_stop"}))["status"] == "ok"
    assert plant.state(1) is RunState.STOPPED


async def test_jog_and_set_point_alone(plant: Plant) -> None:
    response = await plant.set("fan2", {"frequency_hz": 12.5})
    assert response["status"] == "ok"
    assert await plant.tcp.read(2, FREQUENCY_SETPOINT) == [1250]
    assert (await plant.set("fan2", {"command": "jog_forward"}))["status"] == "ok"
    assert plant.state(2) is RunState.RUNNING_FORWARD
    assert (await plant.set("fan2", {"command": "jog_stop"}))["status"] == "ok"
    await eventually(lambda: plant.state(2) is RunState.STOPPED)
    assert (await plant.set("fan2", {"command": "jog_reverse"}))["status"] == "ok"
    assert plant.state(2) is RunState.RUNNING_REVERSE
    assert (await plant.set("fan2", {"command": "jog_stop"}))["status"] == "ok"


async def test_fault_reset(plant: Plant) -> None:
    plant.line.inject_fault(1, 4)
    await plant.probe.wait_for(f"{plant.base}/pump1", lambda s: s["fault_name"] == "OC1")
    refused = await plant.set("pump1", {"command": "run_forward"})
    assert refused["status"] == "error"
    assert refused["error"] == "illegal_command"  # 01H: a faulty drive won't start
    assert refused["exception_code"] == 1
    assert (await plant.set("pump1", {"command": "fault_reset"}))["status"] == "ok"
    assert plant.state(1) is RunState.STOPPED
    await plant.probe.wait_for(f"{plant.base}/pump1", lambda s: s["fault_code"] == 0)


async def test_parameter_writes_and_reads(plant: Plant) -> None:
    response = await plant.set("pump1", {"parameter": "P00.11", "value": 12.5})
    assert response["status"] == "ok"
    assert response["data"] == {
        "parameter": "P00.11",
        "register": "000BH",
        "raw": 125,
        "value": 12.5,
    }
    assert await plant.tcp.read(1, parse_parameter("P00.11")) == [125]

    ram_writes = plant.line.drives[1].ram_writes
    response = await plant.set("pump1", {"parameter": "P00.12", "value": 7.0, "ram_only": True})
    assert response["status"] == "ok"
    assert plant.parameter(1, "P00.12") == 70
    assert plant.line.drives[1].ram_writes == ram_writes + 1

    response = await plant.bridge(
        "write_parameter", {"drive": "fan2", "parameter": "P01.20", "value": 5.0}
    )
    assert response["status"] == "ok"
    assert response["data"]["drive"] == "fan2"
    assert plant.parameter(2, "P01.20") == 50

    response = await plant.bridge("read_parameter", {"drive": "fan2", "parameter": "P01.20"})
    assert response["status"] == "ok"
    assert response["data"] == {
        "drive": "fan2",
        "parameter": "P01.20",
        "register": "0114H",
        "raw": 50,
        "value": 5.0,
    }
    plant.line.set_fault_history(1, [35, 11])
    response = await plant.bridge(
        "read_parameter", {"drive": "pump1", "parameter": "P07.27", "count": 6}
    )
    assert response["data"]["raw"] == [35, 11, 0, 0, 0, 0]

    response = await plant.bridge(
        "write_parameter", {"drive": "pump1", "register": "2001H", "raw": 4000}
    )
    assert response["status"] == "ok"
    assert await plant.tcp.read(1, FREQUENCY_SETPOINT) == [4000]


async def test_a_parameter_beyond_the_common_table_scales_as_the_series_table_says(
    plant: Plant,
) -> None:
    """P03.12 (keypad torque, -300.0-300.0 %) is in the GD350's series table, not the common
    one: written and read back in %, signed, without `decimals` in the message."""
    response = await plant.bridge(
        "write_parameter", {"drive": "pump1", "parameter": "P03.12", "value": -50.0}
    )
    assert response["status"] == "ok", response
    assert plant.parameter(1, "P03.12") == 0xFE0C
    response = await plant.bridge("read_parameter", {"drive": "pump1", "parameter": "P03.12"})
    assert response["data"] == {
        "drive": "pump1",
        "parameter": "P03.12",
        "register": "030CH",
        "raw": 0xFE0C,
        "value": -50.0,
    }


async def test_invalid_value_returns_the_invt_exception_by_name(plant: Plant) -> None:
    # Inside the manual's range, above P00.03 (50.00 Hz) that bounds it: the drive refuses.
    before = plant.parameter(1, "P00.10")
    response = await plant.set("pump1", {"parameter": "P00.10", "value": 60})
    assert response["status"] == "error"
    assert response["error"] == "operation_failure"
    assert response["exception_code"] == 4
    assert "04H" in str(response["message"])
    assert plant.parameter(1, "P00.10") == before  # unchanged


async def test_a_set_point_above_the_drives_maximum_is_refused_naming_it(plant: Plant) -> None:
    """The drive's bare 04H, with the limit it hit: P00.03, read from the drive."""
    response = await plant.set("pump1", {"frequency_hz": 60})
    assert (response["status"], response["error"]) == ("error", "operation_failure")
    assert response["exception_code"] == 4
    assert response["message"] == (
        "04H operation failure: 60.00 Hz is above P00.03 = 50.00 Hz, the drive's maximum"
    )
    # P00.03 raised since the gateway started: 60 Hz passes, and a refusal names the drive's
    # value of now, not the one read at start.
    assert await plant.tcp.request(1, write_pdu(0x0003, 6000)) == write_pdu(0x0003, 6000)
    assert (await plant.set("pump1", {"frequency_hz": 60}))["status"] == "ok"
    response = await plant.set("pump1", {"frequency_hz": 65})
    assert response["message"].endswith("65.00 Hz is above P00.03 = 60.00 Hz, the drive's maximum")


async def test_a_gd20s_max_frequency_is_held_to_its_own_manual(plant: Plant) -> None:
    """The Goodrive20 manual: P00.03 "P00.04-400.00Hz", ◎ (not while running). 450 Hz is
    refused before the wire; while fan2 runs, even 60 Hz is refused by the drive (08H)."""
    above = await plant.set("fan2", {"parameter": "P00.03", "value": 450})
    assert (above["status"], above["error"]) == ("error", "invalid_value")
    assert "outside 0.00..400.00 Hz" in str(above["message"])
    assert plant.parameter(2, "P00.03") == 5000  # unchanged
    assert (await plant.set("fan2", {"command": "run_forward"}))["status"] == "ok"
    running = await plant.set("fan2", {"parameter": "P00.03", "value": 60})
    assert running["error"] == "not_changeable_while_running"
    assert running["exception_code"] == 8
    assert (await plant.set("fan2", {"command": "stop"}))["status"] == "ok"
    await eventually(lambda: plant.state(2) is RunState.STOPPED)
    assert (await plant.set("fan2", {"parameter": "P00.03", "value": 60}))["status"] == "ok"
    assert plant.parameter(2, "P00.03") == 6000


async def test_a_borrowed_range_is_left_to_the_drive_and_its_refusal_says_so(plant: Plant) -> None:
    """pump1 (GD350) takes P01.00 from the Goodrive200A table, unconfirmed for its series: the
    gateway doesn't hold that range against it; the drive's own 04H comes back naming the
    parameter and saying the table is borrowed."""
    response = await plant.set("pump1", {"parameter": "P01.00", "value": 5})
    assert (response["error"], response["exception_code"]) == ("operation_failure", 4)
    assert response["message"] == (
        "04H operation failure: the written value is invalid; P01.00's range is another "
        "series' (the table is borrowed, unconfirmed for gd350): the drive checked it"
    )
    assert (await plant.set("pump1", {"parameter": "P01.00", "value": 1}))["status"] == "ok"
    assert plant.parameter(1, "P01.00") == 1


async def test_a_value_outside_the_manuals_range_or_finer_than_the_register_is_refused(
    plant: Plant,
) -> None:
    """Checked before the wire, as `write` and the console check it: never rounded."""
    outside = await plant.set("pump1", {"parameter": "P00.01", "value": 3})
    assert (outside["status"], outside["error"]) == ("error", "invalid_value")
    assert "outside 0..2" in str(outside["message"])
    finer = await plant.set("pump1", {"parameter": "P00.11", "value": 12.34})
    assert (finer["status"], finer["error"]) == ("error", "invalid_value")
    assert "steps of 0.1 s" in str(finer["message"])
    assert plant.parameter(1, "P00.01") == 2  # unchanged

    response = await plant.bridge(
        "write_parameter", {"drive": "pump1", "parameter": "P07.27", "value": 1}
    )
    assert response["error"] == "parameter_read_only"
    assert response["exception_code"] == 7


async def test_get_forces_a_publication(plant: Plant) -> None:
    mark = len(plant.probe.messages)
    await plant.probe.publish(f"{plant.base}/fan2/get", "")
    state = await plant.probe.wait_for(f"{plant.base}/fan2", after=mark, timeout_s=2)
    assert state.json()["state"] == "stopped"


async def test_retained_command_is_ignored(mosquitto: Mosquitto) -> None:
    """A retained run command, left on the broker by a careless client, reaches the gateway
    each time it subscribes (start, every reconnect): it must never run the drive."""
    base = unique_base_topic()
    topic = f"{base}/pump1/set"
    with simulated_line() as line:
        config = mqtt_config(line.path, mosquitto, base)
        async with mqtt_probe(mosquitto, f"{base}/#") as probe:
            await probe.publish(topic, {"command": "run_forward", "transaction": "r1"}, retain=True)
            async with running_gateway(config):
                response = await probe.wait_for(
                    f"{topic}/response", lambda r: r["transaction"] == "r1"
                )
                assert response.json()["status"] == "error"
                assert response.json()["error"] == "retained"
                await probe.wait_for(f"{base}/pump1", lambda s: "state" in s)
                with line.lock:
                    assert line.drives[1].state(time.monotonic()) is RunState.STOPPED
            await probe.publish(topic, "", retain=True)  # clear it


async def test_command_sent_while_disconnected_is_never_run(plant: Plant) -> None:
    """No session is kept on the broker (clean session): what was published for the gateway
    while it was away is not delivered when it comes back, so a run command can't be replayed."""
    bridge = present(plant.app.mqtt)
    await bridge.stop()
    mark = len(plant.probe.messages)
    await plant.probe.publish(f"{plant.base}/pump1/set", {"command": "run_forward"})
    await bridge.start()
    await bridge.connected.wait()
    await plant.probe.wait_for(
        f"{plant.base}/bridge/state", lambda s: s["state"] == "online", after=mark
    )
    await asyncio.sleep(0.3)  # asserting an absence: the window a response would have come in
    assert not plant.probe.on(f"{plant.base}/pump1/set/response")
    assert plant.state(1) is RunState.STOPPED


async def test_stale_command_is_refused(plant: Plant) -> None:
    response = await plant.set("pump1", {"command": "run_forward", "time": time.time() - 60})
    assert response["status"] == "error"
    assert response["error"] == "stale"
    assert plant.state(1) is RunState.STOPPED
    fresh_ms = int(time.time() * 1000)
    assert (await plant.set("pump1", {"command": "stop", "time": fresh_ms}))["status"] == "ok"
    iso = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(time.time() - 3600))
    assert (await plant.set("pump1", {"command": "stop", "time": iso}))["error"] == "stale"


@pytest.mark.parametrize(
    ("payload", "error"),
    [
        ("not json", "invalid_request"),
        ("[1, 2]", "invalid_request"),
        ({"command": "launch"}, "invalid_request"),
        ({"command": "run_forward", "frequency": 35}, "invalid_request"),
        ({"frequency_hz": -5}, "invalid_value"),
        ({"frequency_hz": "fast"}, "invalid_value"),
        ({"parameter": "P12.01", "value": 1.5}, "invalid_value"),  # in no table: decimals unknown
        ({"parameter": "P00.11", "value": 100000.0}, "invalid_value"),
        ({"parameter": "P00.11", "value": 1e308}, "invalid_value"),  # x10 is inf: no overflow
        ({"parameter": "P00.11", "value": 1e308, "decimals": 1}, "invalid_value"),
        ({"register": "2001H", "value": 1e308}, "invalid_value"),
        ({"parameter": "2001H", "value": 10, "command": "stop"}, "invalid_request"),
        ({}, "invalid_request"),
    ],
)
async def test_bad_commands_are_answered_not_crashed_on(
    plant: Plant, payload: object, error: str
) -> None:
    topic = f"{plant.base}/pump1/set"
    mark = len(plant.probe.messages)
    await plant.probe.publish(topic, payload)
    response = (await plant.probe.wait_for(f"{topic}/response", after=mark)).json()
    assert response["status"] == "error"
    assert response["error"] == error
    # Still working afterwards.
    assert (await plant.set("pump1", {"command": "stop"}))["status"] == "ok"


def on_since(plant: Plant, topic: str, mark: int) -> list[Received]:
    return [m for m in plant.probe.messages[mark:] if m.topic == topic]


async def test_floods_of_bad_commands_are_answered_and_logged_once_a_minute(
    plant: Plant, caplog: pytest.LogCaptureFixture
) -> None:
    log = service_log(caplog)
    topic = f"{plant.base}/pump1/set"
    mark = len(plant.probe.messages)
    for _ in range(200):
        await plant.probe.publish(topic, {"parameter": "P00.11", "value": 1e308})
    await eventually(lambda: len(on_since(plant, f"{topic}/response", mark)) >= 200, 20)
    answers = [m.json() for m in on_since(plant, f"{topic}/response", mark)]
    # Each is refused for what it is; on a loaded machine some find the drive's command lane
    # full first and are answered `busy` (the documented back-pressure), never anything else.
    errors = [(a["status"], a["error"]) for a in answers]
    assert ("error", "invalid_value") in errors
    assert set(errors) <= {("error", "invalid_value"), ("error", "busy")}, set(errors)
    said = lines(log, "gateway")
    assert len(said) <= 2, said
    assert not [line for line in said if "Overflow" in line or line.startswith("ERROR")]


async def test_a_drive_this_gateway_has_not_is_answered_unknown_drive(plant: Plant) -> None:
    response = await plant.set("pump9", {"command": "stop"})
    assert (response["status"], response["error"]) == ("error", "unknown_drive")
    assert "pump1" in str(response["message"])  # the drives it has, named
    assert "transaction" in response
    # The drives' own commands still come once each (one subscription covers them all).
    mark = len(plant.probe.messages)
    assert (await plant.set("pump1", {"command": "stop"}))["status"] == "ok"
    await asyncio.sleep(0.2)
    assert len(on_since(plant, f"{plant.base}/pump1/set/response", mark)) == 1


async def test_offline_drive_answers_offline(plant: Plant) -> None:
    plant.line.set_dead(2, True)
    await plant.probe.wait_for(f"{plant.base}/fan2/availability", lambda a: a["state"] == "offline")
    response = await plant.set("fan2", {"command": "run_forward"})
    assert response["status"] == "error"
    assert response["error"] == "offline"
    assert response["exception_code"] == 0x0B


async def test_a_write_no_reply_confirmed_says_it_may_have_run(plant: Plant) -> None:
    """The drive says nothing to the command: it may still have carried it out (the request
    went out; only its reply is missing). The answer is 0BH, and the command's event says so.
    The drive keeps answering its polls (it frames reads only), so the command itself goes out
    with its retries: a drive silent to everything would owe its polls' replies by then, and
    the command's one attempt would be the marker that asks whether it is back, the command
    itself never sent (on a loaded machine the polls come first)."""
    events = f"{plant.base}/bridge/event"
    mark = len(plant.probe.messages)
    plant.line.know_only(2, {0x03, 0x04, 0x08})
    response = await plant.set("fan2", {"command": "run_forward"})
    assert (response["status"], response["error"]) == ("error", "timeout")
    event = await plant.probe.wait_for(
        events, lambda e: e["type"] == "command" and e["data"]["drive"] == "fan2", after=mark
    )
    data = event.json()["data"]
    assert (data["result"], data["may_have_run"]) == ("timeout", True)
    assert data["times_sent"] >= 1


async def test_commands_disabled(mosquitto: Mosquitto) -> None:
    base = unique_base_topic()
    with simulated_line() as line:
        config = mqtt_config(line.path, mosquitto, base, commands_enabled=False)
        async with mqtt_probe(mosquitto, f"{base}/#") as probe, running_gateway(config):
            await probe.wait_for(f"{base}/bridge/state")
            response = await probe.request(
                f"{base}/pump1/set", {"command": "run_forward"}, f"{base}/pump1/set/response"
            )
            assert response["status"] == "error"
            assert response["error"] == "commands_disabled"
            response = await probe.request(
                f"{base}/bridge/request/write_parameter",
                {"drive": "pump1", "parameter": "P00.11", "value": 1.0},
                f"{base}/bridge/response/write_parameter",
            )
            assert response["error"] == "commands_disabled"
            with line.lock:
                assert line.drives[1].state(time.monotonic()) is RunState.STOPPED
                assert line.drives[1].parameter("P00.11") == 100  # the default 10.0 s


async def test_a_slow_get_holds_back_no_command(plant: Plant) -> None:
    """`/get` polls the drive at poll priority, after any poll of it in progress: under SCADA
    load that takes seconds. Meanwhile a stop, to another drive or to the same one, must go."""
    pump1 = plant.app.poller.drives["pump1"]
    async with pump1.lock:  # a poll of pump1 in progress, for as long as this block lasts
        await plant.probe.publish(f"{plant.base}/pump1/get", "")
        assert (await plant.set("fan2", {"command": "stop"}))["status"] == "ok"
        assert (await plant.set("pump1", {"command": "stop"}))["status"] == "ok"
        mark = len(plant.probe.messages)
    # Once the poll in progress is over, the /get is carried out and the state published.
    await plant.probe.wait_for(f"{plant.base}/pump1", after=mark)


async def test_commands_to_one_drive_run_in_the_order_they_came(plant: Plant) -> None:
    """Published back to back, without waiting for answers, through both command topics."""
    set_topic = f"{plant.base}/pump1/set"
    write_topic = f"{plant.base}/bridge/request/write_parameter"
    response_topics = {set_topic: f"{set_topic}/response"}
    response_topics[write_topic] = f"{plant.base}/bridge/response/write_parameter"
    sent: list[tuple[str, str]] = []
    for step in range(8):
        raw = 1000 + step
        if step % 2:
            topic, payload = write_topic, {"drive": "pump1", "register": "2001H", "raw": raw}
        else:
            topic, payload = set_topic, {"frequency_hz": raw / 100}
        transaction = f"order-{step}"
        await plant.probe.publish(topic, {**payload, "transaction": transaction})
        sent.append((response_topics[topic], transaction))

    last_topic, last = sent[-1]
    await plant.probe.wait_for(last_topic, lambda r: r["transaction"] == last)
    answers = [
        m.json()
        for m in plant.probe.messages
        if m.topic in response_topics.values()
        and str(m.json().get("transaction")).startswith("order-")
    ]
    # Executed, and so answered, in the order they came; the last write is what the drive has.
    assert [a["transaction"] for a in answers] == [transaction for _, transaction in sent]
    assert all(a["status"] == "ok" for a in answers)
    assert await plant.tcp.read(1, FREQUENCY_SETPOINT) == [1007]


async def test_a_command_that_waited_too_long_in_the_gateway_is_stale(
    mosquitto: Mosquitto,
) -> None:
    """Home Assistant's buttons send no `time`: a run pressed while the drive's earlier commands
    were stuck must not run when they clear. Each command to pump1 here takes at least 0.7 s
    (the drive answers that late), so the third waits at least 1.4 s, past the 1 s allowed."""
    base = unique_base_topic()
    drives: list[dict[str, Any]] = [
        {"name": "pump1", "address": 1, "model": "gd350", "timeout_ms": 2000, "poll": []},
        {"name": "fan2", "address": 2, "model": "gd20"},
    ]
    with simulated_line() as line:
        config = mqtt_config(line.path, mosquitto, base, drives=drives, command_max_age_s=1.0)
        async with mqtt_probe(mosquitto, f"{base}/#") as probe, running_gateway(config):
            await probe.wait_for(f"{base}/bridge/state", lambda s: s["state"] == "online")
            line.set_reply_delay(1, 700)
            topic = f"{base}/pump1/set"
            await probe.publish(topic, {"frequency_hz": 20.0, "transaction": "slow-1"})
            await probe.publish(topic, {"frequency_hz": 21.0, "transaction": "slow-2"})
            await probe.publish(topic, {"command": "run_forward", "transaction": "late"})
            response = await probe.wait_for(
                f"{topic}/response", lambda r: r["transaction"] == "late"
            )
            assert response.json()["status"] == "error"
            assert response.json()["error"] == "stale"
            assert "waited" in response.json()["message"]
            with line.lock:
                assert line.drives[1].state(time.monotonic()) is RunState.STOPPED


async def test_read_parameter_over_the_drive_word_limit(plant: Plant) -> None:
    """An INVT drive answers at most 16 words per read; the router splits longer reads, so a
    bridge request may ask for more (20 running values from 3000H here)."""
    response = await plant.bridge(
        "read_parameter", {"drive": "pump1", "register": "3000H", "count": 20}
    )
    assert response["status"] == "ok", response
    assert len(response["data"]["raw"]) == 20
    assert response["data"]["raw"][2] > 0  # 3002H bus voltage: a live value, past no gap
