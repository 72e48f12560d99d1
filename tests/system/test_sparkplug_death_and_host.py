"""Sparkplug B's death certificates and primary host, as a host application sees them: the
NDEATH the broker publishes for a gateway killed with SIGKILL carries the bdSeq of the NBIRTH
before it; with `primary_host_id` the edge node publishes only while that host's STATE says
online, and leaves for the next broker of `mqtt.servers` when it says offline."""

from __future__ import annotations

import asyncio
import json
import logging
import signal
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from gateway.config import MqttConfig
from gateway.mqtt.connection import MQTT_5
from gateway.settings import runtime_settings
from tests.support import eventually, free_port, running_gateway
from tests.support.mosquitto import Mosquitto, mqtt_probe, running_mosquitto, unique_base_topic
from tests.support.mqtt_setup import FAST_POLL, mqtt_config, simulated_line
from tests.support.processes import gateway_process
from tests.support.sparkplug import SparkplugHost, TahuCodec, sparkplug_host, tahu_codec, values

REBIRTH = [{"name": "Node Control/Rebirth", "type": "Boolean", "value": True}]


@pytest.fixture(scope="module")
def codec() -> Iterator[TahuCodec]:
    with tahu_codec() as codec:
        yield codec


def gateway_file(line: str, broker: Mosquitto, group: str) -> dict[str, Any]:
    return {
        "gateway_id": "cabinet-a",
        "modbus_tcp": {"host": "127.0.0.1", "port": free_port()},
        "buses": [{"name": "line1", "port": line, "baudrate": 115200}],
        "drives": [
            {"name": "pump1", "bus": "line1", "address": 1, "model": "gd350", "poll": FAST_POLL},
        ],
        "mqtt": {
            "servers": [f"{broker.host}:{broker.port}"],
            "base_topic": unique_base_topic(),
            "reconnect_max_s": 1.0,
            "sparkplug": {"group_id": group},
        },
    }


async def test_sigkill_gives_the_ndeath_of_the_last_nbirth_and_a_restart_counts_bdseq_on(
    mosquitto: Mosquitto, codec: TahuCodec, tmp_path: Path
) -> None:
    """`payloads-ndeath-will-message`, `payloads-ndeath-bdseq`, `topics-nbirth-bdseq-matching`;
    `topics-nbirth-bdseq-increment` and `message-flow-edge-node-birth-publish-will-message-payload-
    bdSeq` across a restart too: each new CONNECT's bdSeq is the last one's plus one, as the
    TCK's monitor checks for every CONNECT of an edge node id it sees."""
    group = f"plant-{uuid.uuid4().hex[:8]}"
    config = None
    with simulated_line((1,)) as line:
        config = gateway_file(line.path, mosquitto, group)
        with gateway_process(config, tmp_path) as gateway:
            async with sparkplug_host(mosquitto, codec, group, "cabinet-a") as host:
                first = await host.wait_for(host.topic("NBIRTH"), timeout_s=15)
            assert values(first.payload)["bdSeq"] == 0, "a new store: the first CONNECT's is 0"
            # A second connection (the broker restarted): a new will, the next bdSeq.
            mosquitto.stop()
            mosquitto.start()
            async with sparkplug_host(mosquitto, codec, group, "cabinet-a") as host:
                await asyncio.to_thread(gateway.log.wait_for_count, "Sparkplug: born", 2, 15.0)
                mark = host.mark
                await host.command("NCMD", REBIRTH)  # the birth of this connection, seen here
                birth = await host.wait_for(host.topic("NBIRTH"), after=mark)
                bd_seq = values(birth.payload)["bdSeq"]
                assert bd_seq == (values(first.payload)["bdSeq"] + 1) % 256

                gateway.signal(signal.SIGKILL)
                death = await host.wait_for(host.topic("NDEATH"), after=birth.index)
                assert values(death.payload) == {"bdSeq": bd_seq}
                assert "seq" not in death.payload
                assert (death.qos, death.retain) == (1, False)  # the will's QoS 1, not retained

        # The gateway started again: its NBIRTH tells the host it came back (a bdSeq the last
        # NDEATH did not have), and one more than the last CONNECT's.
        async with sparkplug_host(mosquitto, codec, group, "cabinet-a") as host:
            with gateway_process(config, tmp_path):
                again = await host.wait_for(host.topic("NBIRTH"), timeout_s=15)
                assert values(again.payload)["bdSeq"] == (bd_seq + 1) % 256


def state(online: bool, timestamp: int) -> str:
    return json.dumps({"online": online, "timestamp": timestamp})


async def test_primary_host_state_decides_where_and_when(tmp_path: Path, codec: TahuCodec) -> None:
    group = f"plant-{uuid.uuid4().hex[:8]}"
    host_topic = "spBv1.0/STATE/scada"
    with (
        running_mosquitto(tmp_path) as one,
        running_mosquitto(tmp_path) as two,
        simulated_line() as line,
    ):
        config = mqtt_config(line.path, one, unique_base_topic())
        mqtt = MqttConfig.model_validate(
            {
                "servers": [f"{b.host}:{b.port}" for b in (one, two)],
                "base_topic": config.mqtt.base_topic if config.mqtt else "",
                "reconnect_max_s": 1.0,
                "sparkplug": {
                    "group_id": group,
                    "edge_node_id": "cabinet-a",
                    "primary_host_id": "scada",
                },
            }
        )
        config = config.model_copy(update={"mqtt": mqtt})
        async with (
            sparkplug_host(one, codec, group, "cabinet-a") as on_one,
            sparkplug_host(two, codec, group, "cabinet-a") as on_two,
            mqtt_probe(one) as scada_one,
            mqtt_probe(two) as scada_two,
            running_gateway(config) as app,
        ):
            node = app.sparkplug
            assert node is not None
            await asyncio.wait_for(node.connected.wait(), 10)
            await asyncio.sleep(1.0)  # asserting an absence: no birth while the host is away
            assert on_one.messages() == []

            born_at = int(time.time() * 1000)
            await scada_one.publish(host_topic, state(True, born_at), retain=True)
            await scada_two.publish(host_topic, state(True, born_at), retain=True)
            birth = await on_one.wait_for(on_one.topic("NBIRTH"))
            await on_one.wait_for(on_one.topic("DBIRTH", "pump1"), after=birth.index)

            # The host lost broker one (its will there): NDEATH there, then broker two.
            await scada_one.publish(host_topic, state(False, born_at), retain=True)
            death = await on_one.wait_for(on_one.topic("NDEATH"), after=birth.index)
            assert values(death.payload)["bdSeq"] == values(birth.payload)["bdSeq"]
            there = await on_two.wait_for(on_two.topic("NBIRTH"), timeout_s=15)
            await on_two.wait_for(on_two.topic("DBIRTH", "pump1"), after=there.index)
            assert _births(on_one, death.index) == [], "nothing more on broker one"


def _births(host: SparkplugHost, after: int) -> list[str]:
    return [m.topic for m in host.messages(after) if "BIRTH" in m.topic]


async def test_a_reload_ends_the_session_with_an_ndeath_and_counts_bdseq_on(
    mosquitto: Mosquitto, codec: TahuCodec
) -> None:
    group = f"plant-{uuid.uuid4().hex[:8]}"
    with simulated_line() as line:
        config = mqtt_config(
            line.path, mosquitto, unique_base_topic(), sparkplug={"group_id": group}
        )
        async with (
            sparkplug_host(mosquitto, codec, group, "test") as host,
            running_gateway(config) as app,
        ):
            first = await host.wait_for(host.topic("NBIRTH"))
            await host.wait_for(host.topic("DBIRTH", "fan2"), after=first.index)
            assert config.mqtt is not None
            changed = config.mqtt.model_copy(update={"publish_interval_s": 30.0})
            await app.reload(runtime_settings(config.model_copy(update={"mqtt": changed})))
            death = await host.wait_for(host.topic("NDEATH"), after=first.index)
            bd_seq = values(first.payload)["bdSeq"]
            assert values(death.payload) == {"bdSeq": bd_seq}
            again = await host.wait_for(host.topic("NBIRTH"), after=death.index)
            assert values(again.payload)["bdSeq"] == (bd_seq + 1) % 256


async def test_next_server_on_request(tmp_path: Path, codec: TahuCodec) -> None:
    """NCMD "Node Control/Next Server": NDEATH on this broker, then born on the next one."""
    group = f"plant-{uuid.uuid4().hex[:8]}"
    with (
        running_mosquitto(tmp_path) as one,
        running_mosquitto(tmp_path) as two,
        simulated_line() as line,
    ):
        config = mqtt_config(line.path, one, unique_base_topic())
        assert config.mqtt is not None
        mqtt = MqttConfig.model_validate(
            {
                "servers": [f"{b.host}:{b.port}" for b in (one, two)],
                "base_topic": config.mqtt.base_topic,
                "reconnect_max_s": 1.0,
                "sparkplug": {"group_id": group, "edge_node_id": "cabinet-a"},
            }
        )
        async with (
            sparkplug_host(one, codec, group, "cabinet-a") as on_one,
            sparkplug_host(two, codec, group, "cabinet-a") as on_two,
            running_gateway(config.model_copy(update={"mqtt": mqtt})),
        ):
            birth = await on_one.wait_for(on_one.topic("NBIRTH"))
            assert values(birth.payload)["Node Control/Next Server"] is False
            await on_one.command(
                "NCMD", [{"name": "Node Control/Next Server", "type": "Boolean", "value": True}]
            )
            death = await on_one.wait_for(on_one.topic("NDEATH"), after=birth.index)
            assert values(death.payload)["bdSeq"] == values(birth.payload)["bdSeq"]
            there = await on_two.wait_for(on_two.topic("NBIRTH"), timeout_s=15)
            assert values(there.payload)["bdSeq"] == values(birth.payload)["bdSeq"] + 1


async def test_a_clean_stop_publishes_the_ndeath_and_disconnects_with_the_will(
    mosquitto: Mosquitto, codec: TahuCodec
) -> None:
    """`operational-behavior-edge-node-intentional-disconnect-ndeath`,
    `payloads-ndeath-will-message-publisher`: our NDEATH before the DISCONNECT;
    `payloads-ndeath-will-message-publisher-disconnect-mqtt50`: over MQTT 5 (the tests'
    Mosquitto 2) the DISCONNECT's reason code is 0x04, "Disconnect with Will Message", so the
    broker publishes the will too: a second NDEATH of the same bdSeq, which a host ignores. A
    normal DISCONNECT (reason code 0) would discard the will: one NDEATH only."""
    group = f"plant-{uuid.uuid4().hex[:8]}"
    with simulated_line() as line:
        config = mqtt_config(
            line.path, mosquitto, unique_base_topic(), sparkplug={"group_id": group}
        )
        async with sparkplug_host(mosquitto, codec, group, "test") as host:
            async with running_gateway(config) as app:
                birth = await host.wait_for(host.topic("NBIRTH"))
                await host.wait_for(host.topic("DBIRTH", "pump1"), after=birth.index)
                node = app.sparkplug
                assert node is not None
                assert node.session.protocol == MQTT_5
                stopping = time.monotonic()
            stopped_s = time.monotonic() - stopping
            ours = await host.wait_for(host.topic("NDEATH"), after=birth.index)
            will = await host.wait_for(host.topic("NDEATH"), after=ours.index + 1)
            bd_seq = values(birth.payload)["bdSeq"]
            assert values(ours.payload) == values(will.payload) == {"bdSeq": bd_seq}
            # Ours is stamped at the stop, the will at the CONNECT before the birth.
            assert (
                will.payload["timestamp"] <= birth.payload["timestamp"] <= ours.payload["timestamp"]
            )
            assert stopped_s < 2.0, f"the gateway took {stopped_s:.1f} s to stop"


NOT_AUTHORIZED = {5: bytes([0x20, 3, 0, 0x87, 0]), 4: bytes([0x20, 2, 0, 5])}
"""CONNACK "not authorized": MQTT 5's reason code 0x87, 3.1.1's return code 5."""


@dataclass
class RefusingBroker:
    """Listens like a broker and refuses the edge node's CONNECT (as a broker whose ACL denies
    its will's topic does); the bridge's connection is closed unanswered."""

    host: str
    port: int
    edge_node_attempts: int = 0

    async def serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        connect = await reader.read(4096)
        if b"-sparkplug" in connect:
            self.edge_node_attempts += 1
            writer.write(NOT_AUTHORIZED[5 if b"MQTT\x05" in connect else 4])
            await writer.drain()
        writer.close()


class Kept(logging.Handler):
    """Every record of a logger, unfiltered (pytest's caplog handler is one for the whole run,
    and a test before may have put the service's `RepeatFilter` on it)."""

    def __init__(self) -> None:
        super().__init__()
        self.records: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record)


async def test_a_refused_edge_node_is_retried_with_backoff_and_logged_each_time() -> None:
    """Every refusal is counted and logged (through the service's aggregation: at once, then
    one line a minute with the number held back), not one line and then silence."""
    kept = Kept()
    session_log = logging.getLogger("gateway.mqtt.session")
    session_log.addHandler(kept)
    broker = RefusingBroker("127.0.0.1", free_port())
    server = await asyncio.start_server(broker.serve, broker.host, broker.port)
    try:
        async with server:
            with simulated_line() as line:
                config = mqtt_config(
                    line.path, broker, unique_base_topic(), sparkplug={"group_id": "plant"}
                )
                async with running_gateway(config) as app:
                    node = app.sparkplug
                    assert node is not None
                    await eventually(lambda: broker.edge_node_attempts >= 4, within_s=10)
                    failures = node.stats.connect_failures
    finally:
        session_log.removeHandler(kept)
    said = [r for r in kept.records if "(client invt-gateway-test-sparkplug)" in r.getMessage()]
    assert failures >= 3
    assert len(said) >= failures, [r.getMessage() for r in said]
    assert {r.levelno for r in said} == {logging.WARNING}
    assert {getattr(r, "repeat_source", None) for r in said} == {
        "mqtt-connect:invt-gateway-test-sparkplug"
    }
