"""`invt-gateway demo` with MQTT on a machine without a broker: the embedded broker, and the demo
itself end to end (a real subprocess, watched and commanded with aiomqtt)."""

from __future__ import annotations

import asyncio
import contextlib
import os
import signal
import sys
import time
from collections.abc import AsyncIterator
from pathlib import Path

import aiomqtt
import yaml

from gateway.commands.demo import demo_config_text
from gateway.mqtt.embedded_broker import EmbeddedBroker
from tests.mosquitto import Address, mqtt_probe, unique_base_topic
from tests.support import free_port


@contextlib.asynccontextmanager
async def embedded_broker() -> AsyncIterator[Address]:
    broker = EmbeddedBroker("127.0.0.1", 0)
    await broker.start()
    try:
        yield Address(broker.host, broker.port)
    finally:
        await broker.stop()


async def test_embedded_broker_retained_wildcards_and_will() -> None:
    async with embedded_broker() as broker:
        async with aiomqtt.Client(broker.host, broker.port, identifier="publisher") as publisher:
            await publisher.publish("t/bridge/state", '{"state":"online"}', qos=1, retain=True)
            async with mqtt_probe(broker, "t/#") as probe:
                retained = await probe.wait_for("t/bridge/state")
                assert retained.retain
                assert retained.json() == {"state": "online"}
                await publisher.publish("t/pump1", '{"state":"stopped"}', qos=2)
                live = await probe.wait_for("t/pump1")
                assert not live.retain
                await publisher.publish("other/x", "1")
                await publisher.publish("t/pump1/set", "2", qos=0)
                await probe.wait_for("t/pump1/set")
                assert not probe.on("other/x")

                # A client that vanishes without DISCONNECT: its last will goes out, retained.
                mark = len(probe.messages)
                reader, writer = await asyncio.open_connection(broker.host, broker.port)
                writer.write(connect_with_will("vanishing", "t/bridge/state", b"gone"))
                assert await reader.readexactly(4) == bytes.fromhex("20020000")  # CONNACK
                writer.transport.abort()
                will = await probe.wait_for("t/bridge/state", after=mark)
                assert will.payload == b"gone"
        async with mqtt_probe(broker, "t/bridge/state") as late:
            assert (await late.wait_for("t/bridge/state")).payload == b"gone"


def connect_with_will(client_id: str, topic: str, message: bytes) -> bytes:
    """An MQTT 3.1.1 CONNECT, byte by byte from the spec: clean session, will QoS 1 retained."""

    def string(data: bytes) -> bytes:
        return len(data).to_bytes(2, "big") + data

    flags = 0x02 | 0x04 | 0x08 | 0x20
    body = string(b"MQTT") + bytes((4, flags)) + (60).to_bytes(2, "big")
    body += string(client_id.encode()) + string(topic.encode()) + string(message)
    return bytes((0x10, len(body))) + body


async def test_demo_starts_a_broker_when_none_runs(tmp_path: Path) -> None:
    base = unique_base_topic("demo")
    mqtt_port = free_port()
    config = yaml.safe_load(demo_config_text(None))
    config["mqtt"].update({"port": mqtt_port, "base_topic": base})
    config["gateway_id"] = f"demo-{base}"
    config_file = tmp_path / "demo.yaml"
    config_file.write_text(yaml.safe_dump(config), encoding="utf-8")
    process = await asyncio.create_subprocess_exec(
        *(sys.executable, "-m", "gateway", "demo", "--config", str(config_file), "--port", "0"),
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.DEVNULL,
        env={**os.environ, "PYTHONPATH": str(Path(__file__).parent.parent)},
    )
    try:
        broker = Address("127.0.0.1", mqtt_port)
        await wait_listening(broker.host, mqtt_port)
        async with mqtt_probe(broker, f"{base}/#") as probe:
            state = await probe.wait_for(f"{base}/pump1", lambda s: "output_frequency_hz" in s)
            assert state.json()["state"] == "stopped"
            response = await probe.request(
                f"{base}/pump1/set",
                {"command": "run_forward", "frequency_hz": 25.0},
                f"{base}/pump1/set/response",
            )
            assert response["status"] == "ok"
            await probe.wait_for(f"{base}/pump1", lambda s: s["state"] == "running_forward")
        process.send_signal(signal.SIGINT)
        output, _ = await asyncio.wait_for(process.communicate(), 5)
        assert process.returncode == 0
        banner = output.decode()
        assert f"127.0.0.1:{mqtt_port} (embedded" in banner
        assert f"mosquitto_sub -h 127.0.0.1 -p {mqtt_port} -t '{base}/#' -v" in banner
    finally:
        if process.returncode is None:
            process.kill()
            await process.wait()


async def wait_listening(host: str, port: int, within_s: float = 10.0) -> None:
    deadline = time.monotonic() + within_s
    while True:
        try:
            _, writer = await asyncio.open_connection(host, port)
        except OSError:
            assert time.monotonic() < deadline, f"nothing listens on {port}"
            await asyncio.sleep(0.05)
            continue
        writer.close()
        await writer.wait_closed()
        return
