"""Sparkplug B: the gateway as an edge node, each drive a device, as a host application sees it.

Every payload is decoded, and every NCMD and DCMD encoded, by Eclipse Tahu's JavaScript codec
(tests/support/sparkplug.py), on a real Mosquitto, with the simulated drives on a pty line."""

from __future__ import annotations

import asyncio
import itertools
import re
import time
import uuid
from collections.abc import AsyncIterator, Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from gateway.app import Application
from gateway.instruments.simulator import SimulatedLine
from gateway.profile.states import RunState
from gateway.sparkplug import sparkplug_b_pb2 as pb
from tests.support import eventually, running_gateway
from tests.support.mosquitto import Mosquitto, MqttProbe, mqtt_probe, unique_base_topic
from tests.support.mqtt_setup import DRIVES, mqtt_config, simulated_line
from tests.support.service_log import lines, service_log
from tests.support.sparkplug import (
    Message,
    SparkplugHost,
    TahuCodec,
    metrics,
    sparkplug_host,
    tahu_codec,
    values,
)

PUMP_AMPS = 7.3


@pytest.fixture(scope="module")
def codec() -> Iterator[TahuCodec]:
    with tahu_codec() as codec:
        yield codec


@dataclass
class Plant:
    base: str
    line: SimulatedLine
    app: Application
    host: SparkplugHost
    events: MqttProbe
    """The JSON topics' `bridge/event`, where the store's events go."""

    def state(self, address: int) -> RunState:
        with self.line.lock:
            return self.line.drives[address].state(time.monotonic())


def unique_group() -> str:
    return f"plant-{uuid.uuid4().hex[:8]}"


@pytest.fixture
async def plant(mosquitto: Mosquitto, codec: TahuCodec) -> AsyncIterator[Plant]:
    base, group = unique_base_topic(), unique_group()
    with simulated_line() as line:
        line.set_output_current(1, PUMP_AMPS)
        sparkplug = {"group_id": group, "edge_node_id": "cabinet-a"}
        config = mqtt_config(line.path, mosquitto, base, sparkplug=sparkplug)
        async with (
            sparkplug_host(mosquitto, codec, group, "cabinet-a") as host,
            mqtt_probe(mosquitto, f"{base}/bridge/event") as events,
            running_gateway(config) as app,
        ):
            yield Plant(base, line, app, host, events)


def assert_sequence(messages: list[Message]) -> None:
    """From an NBIRTH on, every message's `seq` is the one before plus one, 255 → 0."""
    assert messages[0].topic.split("/")[2] == "NBIRTH"
    assert messages[0].payload["seq"] == 0
    for before, after in itertools.pairwise(messages):
        assert after.payload["seq"] == (before.payload["seq"] + 1) % 256, (before, after)


async def test_births_carry_the_simulated_drives_values(plant: Plant, mosquitto: Mosquitto) -> None:
    host = plant.host
    nbirth = await host.wait_for(host.topic("NBIRTH"))
    node = metrics(nbirth.payload)
    assert node["bdSeq"]["type"] == "Int64"
    assert node["Node Control/Rebirth"] == {**node["Node Control/Rebirth"], "value": False}
    assert "alias" not in node["Node Control/Rebirth"], "a rebirth needs no alias known"
    assert "alias" in node["bdSeq"]
    assert (nbirth.qos, nbirth.retain) == (0, False)

    pump = (await host.wait_for(host.topic("DBIRTH", "pump1"), after=nbirth.index)).payload
    fan = (await host.wait_for(host.topic("DBIRTH", "fan2"), after=nbirth.index)).payload
    born = metrics(pump)
    with plant.line.lock:
        drive = plant.line.drives[1]
        fault_code = drive.fault_code
        setpoint_hz = drive.frequency_hz(time.monotonic())
    # The simulator's values, as Tahu's codec reads them, with their units.
    assert born["output_current_a"]["value"] == PUMP_AMPS
    assert born["output_current_a"]["type"] == "Double"
    assert born["output_current_a"]["properties"]["engUnit"]["value"] == "A"
    assert born["output_frequency_hz"]["value"] == setpoint_hz == 0.0
    assert born["output_frequency_hz"]["properties"]["engUnit"]["value"] == "Hz"
    assert born["fault_code"]["value"] == fault_code == 0
    assert born["state"] == {**born["state"], "value": "stopped", "type": "String"}
    assert born["output_current_a"]["properties"]["readOnly"]["value"] is True
    assert born["set_frequency_hz"]["properties"]["readOnly"]["value"] is False
    assert born["commands/run_forward"]["value"] is False
    assert "last_seen" not in born
    aliases = [
        m["alias"] for p in (nbirth.payload, pump, fan) for m in p["metrics"] if "alias" in m
    ]
    assert len(aliases) == len(set(aliases)), "aliases are unique across the edge node"
    assert values(fan)["state"] == "stopped"
    for birth in (nbirth.payload, pump, fan):
        assert birth["timestamp"] > 0
        assert all(metric["timestamp"] == birth["timestamp"] for metric in birth["metrics"])

    # Report by exception: a new current is one DDATA with that metric alone, by its alias.
    mark = host.mark
    plant.line.set_output_current(1, 9.1)
    alias = born["output_current_a"]["alias"]
    data = await host.wait_for(
        host.topic("DDATA", "pump1"),
        lambda p: any(m["alias"] == alias and m["value"] == 9.1 for m in p["metrics"]),
        after=mark,
    )
    for metric in data.payload["metrics"]:
        assert "name" not in metric
    sent = {m["alias"] for m in data.payload["metrics"]}
    assert born["bus_voltage_v"]["alias"] not in sent, "an unchanged value is not repeated"

    plant.line.inject_fault(1, 4)
    fault = born["fault_code"]["alias"]
    await host.wait_for(
        host.topic("DDATA", "pump1"),
        lambda p: any(m["alias"] == fault and m["value"] == 4 for m in p["metrics"]),
        after=mark,
    )
    assert_sequence(host.messages(nbirth.index))
    for message in host.messages(nbirth.index):
        assert message.qos == 0, message.topic
        assert "timestamp" in message.payload
        # payloads-metric-datatype-req: every birth's metric has its datatype;
        # payloads-metric-datatype-not-req: DDATA's have none (the birth said it), as Tahu's
        # codec and our own decoder both read the bytes.
        ours = pb.Payload.FromString(host.probe.messages[message.index].payload)
        on_wire = [m["datatypeOnWire"] for m in message.payload["metrics"]]
        assert on_wire == [m.HasField("datatype") for m in ours.metrics]
        if "BIRTH" in message.topic:
            assert all(on_wire), message.topic
        else:
            assert on_wire, message.topic
            assert not any(on_wire), message.topic
    # Nothing of it is kept on the broker: a host that comes now finds nothing retained.
    async with mqtt_probe(mosquitto, f"spBv1.0/{host.group}/#") as late:
        await asyncio.sleep(0.3)  # asserting an absence
        assert [m.topic for m in late.messages if m.retain] == []


async def test_a_drive_offline_dies_and_is_born_again(plant: Plant) -> None:
    host = plant.host
    nbirth = await host.wait_for(host.topic("NBIRTH"))
    await host.wait_for(host.topic("DBIRTH", "fan2"), after=nbirth.index)
    mark = host.mark
    plant.line.set_dead(2)
    await host.wait_for(host.topic("DDEATH", "fan2"), after=mark)
    plant.line.set_dead(2, False)
    reborn = await host.wait_for(host.topic("DBIRTH", "fan2"), after=mark)
    assert values(reborn.payload)["state"] == "stopped"
    assert_sequence(host.messages(nbirth.index))


async def test_rebirth_request_gives_a_new_birth(plant: Plant) -> None:
    host = plant.host
    first = await host.wait_for(host.topic("NBIRTH"))
    await host.wait_for(host.topic("DBIRTH", "pump1"), after=first.index)
    mark = host.mark
    await host.command("NCMD", [{"name": "Node Control/Rebirth", "type": "Boolean", "value": True}])
    again = await host.wait_for(host.topic("NBIRTH"), after=mark)
    assert again.payload["seq"] == 0
    # The same connection, so the same will: the bdSeq stays.
    assert values(again.payload)["bdSeq"] == values(first.payload)["bdSeq"]
    pump = await host.wait_for(host.topic("DBIRTH", "pump1"), after=again.index)
    await host.wait_for(host.topic("DBIRTH", "fan2"), after=again.index)
    assert values(pump.payload)["output_current_a"] == PUMP_AMPS
    assert_sequence(host.messages(again.index))


async def test_dcmd_runs_the_drive_and_ddata_acknowledges(plant: Plant) -> None:
    host = plant.host
    nbirth = await host.wait_for(host.topic("NBIRTH"))
    born = metrics((await host.wait_for(host.topic("DBIRTH", "pump1"), after=nbirth.index)).payload)
    mark = host.mark
    await host.command(
        "DCMD",
        [
            {"name": "commands/run_forward", "type": "Boolean", "value": True},
            {"name": "set_frequency_hz", "type": "Double", "value": 20.0},
        ],
        device="pump1",
    )
    await eventually(lambda: plant.state(1) is RunState.RUNNING_FORWARD)
    state, setpoint = born["state"]["alias"], born["set_frequency_hz"]["alias"]
    await host.wait_for(
        host.topic("DDATA", "pump1"),
        lambda p: any(
            m["alias"] == state and m["value"] == "running_forward" for m in p["metrics"]
        ),
        after=mark,
    )
    await host.wait_for(
        host.topic("DDATA", "pump1"),
        lambda p: any(m["alias"] == setpoint and m["value"] == 20.0 for m in p["metrics"]),
        after=mark,
    )
    await plant.events.wait_for(
        f"{plant.base}/bridge/event",
        lambda e: (
            e["type"] == "command"
            and e["data"]["source"] == "sparkplug"
            and e["data"]["command"] == "run_forward"
            and e["data"]["result"] == "ok"
        ),
    )

    # A stop by alias, as a host that learnt the aliases sends it.
    stop = born["commands/stop"]["alias"]
    await host.command("DCMD", [{"alias": stop, "type": "Boolean", "value": True}], device="pump1")
    await eventually(lambda: plant.state(1) is RunState.STOPPED, within_s=10)


RUN_FORWARD = [{"name": "commands/run_forward", "type": "Boolean", "value": True}]


async def test_retained_dcmd_is_refused_and_cleared(plant: Plant, mosquitto: Mosquitto) -> None:
    host = plant.host
    await host.wait_for(host.topic("DBIRTH", "pump1"))
    await host.command("DCMD", RUN_FORWARD, device="pump1", retain=True)
    dcmd = host.topic("DCMD", "pump1")
    await plant.events.wait_for(
        f"{plant.base}/bridge/event",
        lambda e: e["type"] == "retained_command_cleared" and e["data"]["topic"] == dcmd,
    )
    assert plant.state(1) is RunState.STOPPED
    # Gone from the broker: a subscriber that comes now gets no retained command.
    async with mqtt_probe(mosquitto, dcmd) as late:
        await asyncio.sleep(0.3)
        assert [m for m in late.messages if m.payload] == []
    assert plant.state(1) is RunState.STOPPED


async def test_stale_dcmd_is_refused(plant: Plant, caplog: pytest.LogCaptureFixture) -> None:
    host = plant.host
    await host.wait_for(host.topic("DBIRTH", "pump1"))
    await host.command("DCMD", RUN_FORWARD, device="pump1", age_s=3600)
    await eventually(lambda: "DCMD for pump1 refused (stale)" in caplog.text)
    assert plant.state(1) is RunState.STOPPED


async def test_dcmd_of_a_monitoring_only_gateway_is_refused(
    mosquitto: Mosquitto, codec: TahuCodec, caplog: pytest.LogCaptureFixture
) -> None:
    group = unique_group()
    with simulated_line() as line:
        sparkplug = {"group_id": group, "edge_node_id": "watch"}
        config = mqtt_config(
            line.path, mosquitto, unique_base_topic(), sparkplug=sparkplug, commands_enabled=False
        )
        async with (
            sparkplug_host(mosquitto, codec, group, "watch") as host,
            running_gateway(config),
        ):
            born = metrics((await host.wait_for(host.topic("DBIRTH", "pump1"))).payload)
            assert "commands/run_forward" not in born
            assert born["set_frequency_hz"]["properties"]["readOnly"]["value"] is True
            await host.command("DCMD", RUN_FORWARD, device="pump1")
            await eventually(lambda: "refused (commands_disabled)" in caplog.text)
            with line.lock:
                assert line.drives[1].state(time.monotonic()) is RunState.STOPPED


async def test_ddata_keeps_the_deadband(mosquitto: Mosquitto, codec: TahuCodec) -> None:
    """`mqtt.report`'s deadband holds for DDATA too: a move inside it is not sent."""
    group = unique_group()
    with simulated_line() as line:
        line.set_output_current(1, 7.0)
        sparkplug = {"group_id": group, "edge_node_id": "banded"}
        report = {"keys": {"output_current_a": {"deadband": 1.0}}}
        drives = [{**DRIVES[0], "report": report}, DRIVES[1]]
        config = mqtt_config(
            line.path, mosquitto, unique_base_topic(), drives=drives, sparkplug=sparkplug
        )
        async with (
            sparkplug_host(mosquitto, codec, group, "banded") as host,
            running_gateway(config),
        ):
            born = metrics((await host.wait_for(host.topic("DBIRTH", "pump1"))).payload)
            amps = born["output_current_a"]["alias"]
            mark = host.mark
            line.set_output_current(1, 7.6)  # inside the deadband of 1 A
            await asyncio.sleep(1.0)  # three polls of the running values at least
            line.set_output_current(1, 8.5)  # beyond it
            # Live values only: what was polled before the node's first birth may still be on
            # its way as historical DDATA (`isHistorical`, the outage buffer's), 7.0 among it.
            data = await host.wait_for(
                host.topic("DDATA", "pump1"),
                lambda p: any(
                    m["alias"] == amps and not m.get("isHistorical") for m in p["metrics"]
                ),
                after=mark,
            )
            sent = [
                m["value"]
                for m in data.payload["metrics"]
                if m["alias"] == amps and not m.get("isHistorical")
            ]
            assert sent == [8.5]


def raw_dcmd(*metrics: pb.Payload.Metric) -> bytes:
    """What Tahu's codec would never send: built field by field."""
    return pb.Payload(timestamp=int(time.time() * 1000), metrics=metrics).SerializeToString()


async def test_malformed_dcmds_are_refused_counted_and_logged_once_a_minute(
    plant: Plant, caplog: pytest.LogCaptureFixture
) -> None:
    log = service_log(caplog)
    host = plant.host
    born = metrics((await host.wait_for(host.topic("DBIRTH", "pump1"))).payload)
    topic = host.topic("DCMD", "pump1")
    # A name that is not UTF-8 (protobuf hands it over as bytes).
    named = raw_dcmd(pb.Payload.Metric(name="Xommands/run_forward", datatype=pb.Boolean))
    named = named.replace(b"Xommands", b"\xff\xfemmands")
    # An int_value where the datatype (Float) says float_value.
    wrong_field = raw_dcmd(
        pb.Payload.Metric(name="set_frequency_hz", datatype=pb.Float, int_value=20)
    )
    # A name, and the alias of another metric: which one is meant?
    stop_alias = born["commands/stop"]["alias"]
    both = host.codec.encode(
        {
            "timestamp": int(time.time() * 1000),
            "metrics": [
                {
                    "name": "commands/run_forward",
                    "alias": stop_alias,
                    "type": "Boolean",
                    "value": True,
                }
            ],
        }
    )
    for data in (named, wrong_field, both):
        await host.probe.publish(topic, data)
    for _ in range(2000):
        await host.probe.publish(topic, b"\xff\x01garbage")
    node = plant.app.sparkplug
    assert node is not None
    # Each refused as invalid (or, past 16 waiting for the drive's lane, busy): counted.
    await eventually(
        lambda: node.commands.statuses["invalid_request"] + node.stats.busy >= 2003, 30
    )
    assert node.commands.statuses["invalid_request"] >= 3
    assert plant.state(1) is RunState.STOPPED  # nothing of them run
    said = lines(log, "gateway.sparkplug")
    assert len(said) <= 3, said  # one line a minute for each kind of refusal
    assert not [line for line in said if line.startswith("ERROR")], said
    # The drive still takes a good DCMD.
    await host.command("DCMD", RUN_FORWARD, device="pump1")
    await eventually(lambda: plant.state(1) is RunState.RUNNING_FORWARD)


MQTT_PAGE = Path(__file__).resolve().parents[2] / "docs" / "pages" / "mqtt.md"


async def test_the_documented_sizes_are_the_measured_ones(plant: Plant) -> None:
    """docs/pages/mqtt.md's cost table: NBIRTH ~220 bytes, a GD350's DBIRTH ~2.1 kB, one changed
    value's DDATA 29 bytes (within 10 %: a version or gateway id of another length)."""
    page = MQTT_PAGE.read_text(encoding="utf-8")
    documented = [
        _figure(page, r"NBIRTH \(~(\d+) bytes\)"),
        _figure(page, r"~([\d.]+) kB for a GD350") * 1000,
        _figure(page, r"a DDATA of that metric, (\d+) bytes"),
    ]
    host = plant.host
    nbirth = await host.wait_for(host.topic("NBIRTH"))
    pump = await host.wait_for(host.topic("DBIRTH", "pump1"), after=nbirth.index)
    amps = metrics(pump.payload)["output_current_a"]["alias"]
    mark = host.mark
    plant.line.set_output_current(1, 9.1)
    data = await host.wait_for(
        host.topic("DDATA", "pump1"),
        lambda p: [m["alias"] for m in p["metrics"]] == [amps],
        after=mark,
    )
    measured = [len(host.probe.messages[m.index].payload) for m in (nbirth, pump, data)]
    for size, said in zip(measured, documented, strict=True):
        assert abs(size - said) <= said * 0.1, (measured, documented)


def _figure(page: str, pattern: str) -> float:
    found = re.search(pattern, page)
    assert found is not None, f"docs/pages/mqtt.md no longer says {pattern}"
    return float(found[1])
