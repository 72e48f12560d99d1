"""`invt-gateway demo` with MQTT on a machine without a broker: the embedded broker, and the demo
itself end to end (a real subprocess, watched and commanded with aiomqtt)."""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import signal
import subprocess
import sys
import time
import uuid
from collections.abc import AsyncIterator
from pathlib import Path

import aiomqtt
import yaml

from gateway.exit_codes import EXIT_STARTUP
from gateway.instruments.commands.demo import demo_config_text
from gateway.instruments.embedded_broker import EmbeddedBroker
from tests.support import free_port
from tests.support.mosquitto import (
    Address,
    BrokerAddress,
    Mosquitto,
    mqtt_probe,
    retained_messages,
    unique_base_topic,
)
from tests.support.processes import LineCollector, entry_point


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
    config["console"]["port"] = 0  # a free one: demos run side by side here
    config["mqtt"].update({"port": mqtt_port, "base_topic": base})
    config["gateway_id"] = f"demo-{base}"
    config_file = tmp_path / "demo.yaml"
    config_file.write_text(yaml.safe_dump(config), encoding="utf-8")
    process = await asyncio.create_subprocess_exec(
        *(sys.executable, "-m", "gateway", "demo", "--config", str(config_file), "--port", "0"),
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.DEVNULL,
        env={**os.environ, "PYTHONPATH": str(Path(__file__).parents[2])},
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
            await asyncio.sleep(0.05)  # polled with a deadline: another process's port
            continue
        writer.close()
        await writer.wait_closed()
        return


class DemoProcess:
    """`invt-gateway demo ARGS`, its stdout and stderr collected line by line."""

    def __init__(self, *args: str) -> None:
        self.process = subprocess.Popen(
            [entry_point(), "demo", *args],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        self.out = LineCollector(self.process.stdout)
        self.err = LineCollector(self.process.stderr)

    async def wait_for(self, text: str, stream: str = "out") -> str:
        collector = self.out if stream == "out" else self.err
        return await asyncio.to_thread(collector.wait_for, text)

    async def interrupt(self) -> int:
        """Ctrl-C, as a person stops it; the exit code."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
        try:
            return await asyncio.to_thread(self.process.wait, 10)
        finally:
            if self.process.poll() is None:
                self.process.kill()
                await asyncio.to_thread(self.process.wait, 5)
            for collector, stream in (
                (self.out, self.process.stdout),
                (self.err, self.process.stderr),
            ):
                collector.join()
                if stream is not None:
                    stream.close()


async def test_the_demo_raises_no_warning_about_its_own_broker(tmp_path: Path) -> None:
    """The embedded broker speaks MQTT 3.1.1, which the gateway fully works with: the demo
    warned "speaks MQTT 3.1.1 only" at every start (twice with Sparkplug, its own connection)."""
    base = unique_base_topic("demo")
    config = yaml.safe_load(demo_config_text(None))
    config["console"]["port"] = 0
    config["mqtt"].update(
        {"port": free_port(), "base_topic": base, "sparkplug": {"group_id": "demo"}}
    )
    config["gateway_id"] = f"demo-{base}"
    config_file = tmp_path / "demo.yaml"
    config_file.write_text(yaml.safe_dump(config), encoding="utf-8")
    demo = DemoProcess("--config", str(config_file), "--port", str(free_port()))
    try:
        await demo.wait_for("Stop with Ctrl-C")
        await demo.wait_for("Home Assistant discovery published", "err")
        await demo.wait_for("Sparkplug: born as", "err")
    finally:
        assert await demo.interrupt() == 0, demo.err.text
    assert "(embedded" in demo.out.text
    assert "3.1.1" in demo.err.text  # said, as information
    complaints = [
        line for line in demo.err.text.splitlines() if " WARNING " in line or " ERROR " in line
    ]
    assert complaints == []


async def test_watch_watches_the_running_demo_and_no_two_client_ids_collide(
    tmp_path: Path,
) -> None:
    # The demo's broker runs in this process, so the test sees its sessions by client id.
    broker = EmbeddedBroker("127.0.0.1", 0)
    await broker.start()
    base = unique_base_topic("demo")
    config = yaml.safe_load(demo_config_text(None))  # gateway_id "demo"
    config["console"]["port"] = 0
    config["mqtt"].update({"port": broker.port, "base_topic": base})
    config_file = tmp_path / "demo.yaml"
    config_file.write_text(yaml.safe_dump(config), encoding="utf-8")
    modbus_port = free_port()
    demos: list[DemoProcess] = []
    try:
        first = DemoProcess("--config", str(config_file), "--port", str(modbus_port))
        demos.append(first)
        await first.wait_for("Stop with Ctrl-C")
        # The banner's own watch line, given the demo's Modbus-TCP port besides: a second
        # gateway could not bind it, a watcher doesn't try.
        watch_line = await first.wait_for("demo --watch")
        watch_args = watch_line.split("invt-gateway demo ")[1].split("  ")[0].split()
        assert watch_args == [
            *("--watch", "--config", str(config_file), "--mqtt-port", str(broker.port))
        ]
        watcher = DemoProcess(*watch_args, "--port", str(modbus_port))
        demos.append(watcher)

        state = await watcher.wait_for(f"{base}/pump1 ")
        assert json.loads(state.split(" ", 1)[1])["state"] == "stopped"
        watching = await watcher.wait_for("watching", "err")
        assert watching == f"watching {base}/# at 127.0.0.1:{broker.port} (Ctrl-C to stop)"
        # The demo and the watcher connected at once: with one client id between them (or
        # with a service whose gateway id is "demo"), the broker would hold only one session.
        ids = await sessions(broker, 2)
        assert sorted(i.rsplit("-", 1)[0] for i in ids) == [
            "invt-gateway-demo",
            "invt-gateway-watch",
        ]
        assert watcher.process.poll() is None, watcher.err.text
        assert "Modbus-TCP" not in watcher.out.text + watcher.err.text  # no gateway in it
    finally:
        # Every demo stopped, and the broker whatever they did: a server left listening holds
        # uvloop's close of this test's loop (and with it the whole run) forever.
        codes = await asyncio.gather(*(demo.interrupt() for demo in demos), return_exceptions=True)
        await broker.stop()
    assert codes[0] == 0, codes


async def test_a_second_demo_on_the_broker_leaves_the_first_ones_entities_and_state_alone(
    tmp_path: Path, mosquitto: Mosquitto
) -> None:
    """A second demo on a broker where one runs: with its own Modbus-TCP port it is refused
    (it would share the first's gateway id, topics and Home Assistant entities); on the
    first's port it fails to start. Either way it exits, and the first's discovery configs
    and its "online" stay as they were: a failed demo cleared them all, and said "offline"."""
    base = unique_base_topic("demo")
    config = yaml.safe_load(demo_config_text(None))
    config["console"]["port"] = 0
    config["mqtt"].update({"port": mosquitto.port, "base_topic": base})
    config_file = tmp_path / "demo.yaml"
    config_file.write_text(yaml.safe_dump(config), encoding="utf-8")
    modbus_port = free_port()
    first = DemoProcess("--config", str(config_file), "--port", str(modbus_port))
    try:
        await first.wait_for("Home Assistant discovery published", "err")
        entities = await retained_messages(mosquitto, "homeassistant/#")
        assert entities
        async with mqtt_probe(mosquitto, f"{base}/bridge/state") as probe:
            online = await probe.wait_for(f"{base}/bridge/state")
            assert online.json()["state"] == "online"
            for port in (free_port(), modbus_port):
                second = DemoProcess("--config", str(config_file), "--port", str(port))
                code = await asyncio.to_thread(second.process.wait, 20)
                await second.interrupt()
                assert code == EXIT_STARTUP, second.err.text
                if port != modbus_port:
                    assert "gateway 'demo' is online already" in second.err.text
                assert "cleared its" not in second.err.text
            assert await retained_messages(mosquitto, "homeassistant/#") == entities
            await asyncio.sleep(0.3)  # asserting an absence: no "offline" for the first
            assert [m.json()["state"] for m in probe.messages] == ["online"]
        assert first.process.poll() is None
    finally:
        assert await first.interrupt() == 0, first.err.text
    assert await retained_messages(mosquitto, "homeassistant/#") == {}  # its own, at its stop


async def sessions(broker: EmbeddedBroker, count: int, within_s: float = 15.0) -> list[str]:
    """The broker's client ids once it holds `count` sessions at once (a gateway's short side
    connection, `<id>-cleanup` for the discovery clean-up at start, is not one of them)."""

    def held() -> list[str]:
        return sorted(i for i in broker.sessions if not i.endswith("-cleanup"))

    deadline = time.monotonic() + within_s
    while len(held()) < count:
        assert time.monotonic() < deadline, f"sessions: {sorted(broker.sessions)}"
        await asyncio.sleep(0.05)  # polled with a deadline: the broker's sessions, no event
    return held()


async def retained_under(broker: BrokerAddress, topic_filter: str) -> list[str]:
    """The topics a fresh subscriber to `topic_filter` is handed as retained: all of them
    arrive before a marker published after subscribing (one session, in order)."""
    marker = f"{topic_filter.rstrip('#/')}/marker-{uuid.uuid4().hex[:8]}"
    async with mqtt_probe(broker, topic_filter) as probe:
        await probe.publish(marker, "end")
        await probe.wait_for(marker)
        return [m.topic for m in probe.messages if m.retain and m.payload]


async def test_the_demo_leaves_no_discovery_configs_on_a_shared_broker(
    tmp_path: Path, mosquitto: Mosquitto
) -> None:
    config = yaml.safe_load(demo_config_text(None))
    config["console"]["port"] = 0
    config["mqtt"].update({"port": mosquitto.port, "base_topic": unique_base_topic("demo")})
    config_file = tmp_path / "demo.yaml"
    config_file.write_text(yaml.safe_dump(config), encoding="utf-8")
    demo = DemoProcess("--config", str(config_file), "--port", str(free_port()))
    try:
        published = await demo.wait_for("Home Assistant discovery published", "err")
        count = int(published.split("(")[1].split()[0])
        assert count > 0
        while_running = await retained_under(mosquitto, "homeassistant/#")
        assert len(while_running) == count, while_running  # the demo's, retained
    finally:
        assert await demo.interrupt() == 0, demo.err.text
    assert await retained_under(mosquitto, "homeassistant/#") == []
    assert f"cleared its {count} Home Assistant discovery configs" in demo.err.text


async def test_a_demo_of_a_configuration_listing_servers_runs_on_one_broker(
    tmp_path: Path,
) -> None:
    """`mqtt.servers` (a cluster's nodes) in the demo's file: the demo uses the first; with
    `--mqtt-port` its host on that port. Nothing answers there, so the demo starts its broker
    there, and the gateway publishes to it (it used to go on with the list, away from it)."""
    base = unique_base_topic("demo")
    config = yaml.safe_load(demo_config_text(None))
    config["console"]["port"] = 0
    del config["mqtt"]["host"], config["mqtt"]["port"]
    listed = [f"127.0.0.1:{free_port()}", f"127.0.0.1:{free_port()}"]
    config["mqtt"].update({"servers": listed, "base_topic": base})
    config["gateway_id"] = f"demo-{base}"
    config_file = tmp_path / "demo.yaml"
    config_file.write_text(yaml.safe_dump(config), encoding="utf-8")
    mqtt_port = free_port()
    demo = DemoProcess(
        "--config", str(config_file), "--port", str(free_port()), "--mqtt-port", str(mqtt_port)
    )
    try:
        await demo.wait_for("Stop with Ctrl-C")
        warning = await demo.wait_for("mqtt.servers lists 2 brokers", "err")
        assert listed[0] in warning
        async with mqtt_probe(Address("127.0.0.1", mqtt_port), f"{base}/bridge/state") as probe:
            online = await probe.wait_for(f"{base}/bridge/state", lambda s: s["state"] == "online")
            assert online.json()["server"] == f"127.0.0.1:{mqtt_port}"
        assert f"127.0.0.1:{mqtt_port} (embedded" in demo.out.text
        assert f"-p {mqtt_port}" in demo.out.text
    finally:
        assert await demo.interrupt() == 0, demo.err.text
