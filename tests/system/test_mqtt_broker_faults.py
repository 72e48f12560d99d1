"""Broker faults: down at start, killed and restarted mid-run, a gateway killed (last will), and two
gateways sharing one broker. Modbus-TCP must not notice any of it."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import signal
import sys
import time
from pathlib import Path

import pytest
import yaml

from gateway.profile.invt import STATE_WORD_1
from gateway.profile.states import RunState
from tests.support import TcpClient, eventually, free_port, present, running_gateway
from tests.support.mosquitto import BrokerProxy, Mosquitto, mqtt_probe, unique_base_topic
from tests.support.mqtt_setup import DRIVES, mqtt_config, simulated_line


async def read_for(tcp: TcpClient, seconds: float) -> list[float]:
    """Read state word 1 of drive 1 over Modbus-TCP for `seconds`; each read's latency."""
    latencies = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        start = time.monotonic()
        assert await tcp.read(1, STATE_WORD_1) == [RunState.STOPPED]
        latencies.append(time.monotonic() - start)
    return latencies


async def test_broker_down_at_start(tmp_path: Path) -> None:
    broker = Mosquitto(tmp_path)  # configured, not started
    base = unique_base_topic()
    with simulated_line() as line:
        config = mqtt_config(line.path, broker, base)
        started = time.monotonic()
        async with running_gateway(config) as app:
            assert time.monotonic() - started < 3  # the gateway didn't wait for the broker
            tcp = await TcpClient.connect(app.tcp.port)
            try:
                assert len(await read_for(tcp, 0.5)) > 5
            finally:
                await tcp.close()
            broker.start()
            try:
                async with mqtt_probe(broker, f"{base}/#") as probe:
                    await probe.wait_for(f"{base}/bridge/state", lambda s: s["state"] == "online")
                    await probe.wait_for(f"{base}/pump1", lambda s: s["state"] == "stopped")
            finally:
                broker.stop()


async def test_broker_killed_and_restarted(mosquitto: Mosquitto) -> None:
    base = unique_base_topic()
    with simulated_line() as line:
        config = mqtt_config(line.path, mosquitto, base)
        async with running_gateway(config) as app:
            async with mqtt_probe(mosquitto, f"{base}/#") as probe:
                await probe.wait_for(f"{base}/pump1", lambda s: s["state"] == "stopped")
            tcp = await TcpClient.connect(app.tcp.port)
            try:
                with_broker = await read_for(tcp, 1.0)
                mosquitto.stop()
                await eventually(
                    lambda: not present(app.mqtt).connected.is_set(), what="broker lost"
                )
                line.inject_fault(2, 13)  # while the broker is away: the event must wait
                without_broker = await read_for(tcp, 2.0)
            finally:
                await tcp.close()
            # Modbus-TCP didn't notice: as many reads, no slower.
            assert len(without_broker) >= 1.5 * len(with_broker)
            assert max(without_broker) < 1.5  # a bridge blocking the loop would stall for seconds
            assert present(app.mqtt).connected.is_set() is False

            mosquitto.start()  # a restarted broker without persistence: nothing retained
            async with mqtt_probe(mosquitto, f"{base}/#") as probe:
                online = await probe.wait_for(f"{base}/bridge/state", timeout_s=10)
                assert online.json()["state"] == "online"
                # Republished after the reconnect, retained: the broker had forgotten them.
                state = await probe.wait_for(f"{base}/fan2", lambda s: s["fault_name"] == "SPI")
                assert state.retain or state.json()["state"] == "fault"
                availability = await probe.wait_for(f"{base}/pump1/availability")
                assert availability.json() == {"state": "online"}
                event = await probe.wait_for(
                    f"{base}/bridge/event", lambda e: e["type"] == "fault_raised"
                )
                assert event.json()["data"]["drive"] == "fan2"
            assert present(app.mqtt).stats.connects == 2


async def test_last_will_when_the_gateway_is_killed(mosquitto: Mosquitto, tmp_path: Path) -> None:
    base = unique_base_topic()
    with simulated_line() as line:
        config_file = tmp_path / "gateway.yaml"
        config_file.write_text(
            yaml.safe_dump(
                {
                    "gateway_id": "killed",
                    "modbus_tcp": {"host": "127.0.0.1", "port": free_port()},
                    "buses": [{"name": "line1", "port": line.path, "baudrate": 115200}],
                    "drives": [{"bus": "line1", **d} for d in DRIVES],
                    "mqtt": {
                        "host": mosquitto.host,
                        "port": mosquitto.port,
                        "base_topic": base,
                        "keepalive_s": 60,
                    },
                }
            ),
            encoding="utf-8",
        )
        async with mqtt_probe(mosquitto, f"{base}/bridge/state") as probe:
            process = await asyncio.create_subprocess_exec(
                *(sys.executable, "-m", "gateway", "run", "--config", str(config_file)),
                stdout=asyncio.subprocess.DEVNULL,
                stderr=asyncio.subprocess.DEVNULL,
                env={**os.environ, "PYTHONPATH": str(Path(__file__).parents[2])},
            )
            try:
                await probe.wait_for(f"{base}/bridge/state", lambda s: s["state"] == "online")
                mark = len(probe.messages)
                process.send_signal(signal.SIGKILL)
                started = time.monotonic()
                will = await probe.wait_for(
                    f"{base}/bridge/state", lambda s: s["state"] == "offline", after=mark
                )
                # The broker sees the socket close: no need to wait for the keepalive (60 s).
                assert time.monotonic() - started < 5
                assert will.json() == {"state": "offline"}
            finally:
                with contextlib.suppress(ProcessLookupError):
                    process.kill()
                await process.wait()
        # And it stays retained for whoever looks later.
        async with mqtt_probe(mosquitto, f"{base}/bridge/state") as late:
            retained = await late.wait_for(f"{base}/bridge/state")
            assert retained.retain
            assert retained.json() == {"state": "offline"}


async def test_clean_stop_publishes_offline(mosquitto: Mosquitto) -> None:
    base = unique_base_topic()
    with simulated_line() as line:
        config = mqtt_config(line.path, mosquitto, base)
        async with mqtt_probe(mosquitto, f"{base}/bridge/state") as probe:
            async with running_gateway(config):
                await probe.wait_for(f"{base}/bridge/state", lambda s: s["state"] == "online")
                mark = len(probe.messages)
            await probe.wait_for(
                f"{base}/bridge/state", lambda s: s["state"] == "offline", after=mark
            )


async def test_two_gateways_on_one_broker(mosquitto: Mosquitto) -> None:
    north_base, south_base = unique_base_topic("north"), unique_base_topic("south")
    with simulated_line() as north_line, simulated_line() as south_line:
        north = mqtt_config(north_line.path, mosquitto, north_base, gateway_id="north")
        south = mqtt_config(south_line.path, mosquitto, south_base, gateway_id="south")
        async with (
            mqtt_probe(mosquitto, f"{north_base}/#", f"{south_base}/#") as probe,
            running_gateway(north) as north_app,
            running_gateway(south) as south_app,
        ):
            for base in (north_base, south_base):
                await probe.wait_for(f"{base}/bridge/state", lambda s: s["state"] == "online")
                await probe.wait_for(f"{base}/pump1", lambda s: s["state"] == "stopped")
            response = await probe.request(
                f"{north_base}/pump1/set",
                {"command": "run_forward", "frequency_hz": 20.0},
                f"{north_base}/pump1/set/response",
            )
            assert response["status"] == "ok"
            await probe.wait_for(f"{north_base}/pump1", lambda s: s["state"] == "running_forward")
            await asyncio.sleep(0.5)  # asserting an absence: south's polls would have shown it
            with north_line.lock, south_line.lock:
                now = time.monotonic()
                assert north_line.drives[1].state(now) is RunState.RUNNING_FORWARD
                assert south_line.drives[1].state(now) is RunState.STOPPED
            assert not [
                m for m in probe.on(f"{south_base}/pump1") if "running" in m.json()["state"]
            ]
            assert not probe.on(f"{south_base}/pump1/set/response")
            # Distinct client ids: neither threw the other off the broker.
            assert present(north_app.mqtt).stats.connects == 1
            assert present(south_app.mqtt).stats.connects == 1


async def test_same_base_topic_is_reported(
    mosquitto: Mosquitto, caplog: pytest.LogCaptureFixture
) -> None:
    base = unique_base_topic()
    with simulated_line() as one_line, simulated_line() as other_line:
        one = mqtt_config(one_line.path, mosquitto, base, gateway_id="one")
        other = mqtt_config(other_line.path, mosquitto, base, gateway_id="other")
        # Both started while the broker is away: neither can be refused at its start
        # (tests/system/test_mqtt_shared_broker.py), so they meet once it is back.
        mosquitto.stop()
        with caplog.at_level(logging.ERROR, logger="gateway.mqtt.kinds"):
            async with running_gateway(one) as one_app, running_gateway(other) as other_app:
                mosquitto.start()
                # Each hears of the other, whichever published its info last (kinds.GatewayInfo).
                await eventually(
                    lambda: (
                        present(one_app.mqtt).stats.conflicts
                        and present(other_app.mqtt).stats.conflicts
                    ),
                    within_s=10.0,
                )
        assert "gateway 'other' also publishes under" in caplog.text
        assert "gateway 'one' also publishes under" in caplog.text


async def test_an_event_being_published_when_the_connection_breaks_is_not_lost(
    mosquitto: Mosquitto,
) -> None:
    """The gateway reaches the broker through a relay that holds back what it sends, then
    breaks the connection while the bridge waits for the broker to acknowledge a fault event.
    The event was taken from the outbox but never arrived: it must go out after the reconnect.
    The probe is connected to the broker directly, so it sees everything, nothing twice."""
    base = unique_base_topic()
    async with BrokerProxy(mosquitto) as relay:
        with simulated_line() as line:
            config = mqtt_config(line.path, relay, base)
            async with (
                mqtt_probe(mosquitto, f"{base}/#") as probe,
                running_gateway(config) as app,
            ):
                await probe.wait_for(f"{base}/fan2", lambda s: s["state"] == "stopped")
                relay.freeze()
                mark = len(probe.messages)
                line.inject_fault(2, 13)
                await relay.wait_held(b"fault_raised")  # published; no acknowledgement comes
                relay.cut()
                event = await probe.wait_for(
                    f"{base}/bridge/event", lambda e: e["type"] == "fault_raised", after=mark
                )
                assert event.json()["data"]["drive"] == "fan2"
                assert event.json()["data"]["fault_code"] == 13
                assert app.events.stats.events_dropped == 0
                assert present(app.mqtt).stats.connects == 2
