"""The console's diagnostics against the gateway on the simulated line: the line's counters per
bus and per drive since start and in the last minute, the Modbus-TCP clients, the MQTT session
with a real Mosquitto (and without one)."""

from __future__ import annotations

import logging
import struct
from typing import Any

import pytest

from gateway.app import Application
from gateway.config import GatewayConfig, MqttConfig
from gateway.instruments.embedded_broker import EmbeddedBroker
from gateway.instruments.simulator import SimulatedLine
from gateway.settings import runtime_settings
from tests.support import TcpClient, eventually, free_port, present, running_gateway
from tests.support.console_support import (
    OPERATOR_PASSWORD,
    VIEWER_PASSWORD,
    ConsoleClient,
    console_client,
    console_config,
)
from tests.support.mosquitto import Mosquitto

NOT_A_REGISTER = 0x0F00
ILLEGAL_DATA_ADDRESS = 0x02


def with_mqtt(config: GatewayConfig, host: str, port: int) -> GatewayConfig:
    mqtt = MqttConfig.model_validate(
        {"host": host, "port": port, "base_topic": "diagnostics", "reconnect_max_s": 1.0}
    )
    return config.model_copy(update={"mqtt": mqtt})


async def diagnostics(web: ConsoleClient) -> dict[str, Any]:
    found: dict[str, Any] = await web.get_json("/api/diagnostics")
    return found


def drive_counts(found: dict[str, Any], drive: str) -> dict[str, Any]:
    (bus,) = found["buses"]
    counted: dict[str, Any] = next(d for d in bus["drives"] if d["drive"] == drive)
    return counted


async def test_line_counters_per_drive_since_start_and_in_the_last_minute(
    line: SimulatedLine,
) -> None:
    async with running_gateway(console_config(line.path)) as app, console_client(app) as web:
        assert (await web.login("victor", VIEWER_PASSWORD)).status == 200
        # A SCADA read of a register pump1 doesn't have: the drive answers exception 02H.
        client = await TcpClient.connect(app.tcp.port)
        reply = await client.request(1, struct.pack(">BHH", 0x03, NOT_A_REGISTER, 1))
        assert reply == bytes([0x83, ILLEGAL_DATA_ADDRESS])
        line.set_dead(2)

        async def fan2_timed_out() -> bool:
            counted = drive_counts(await diagnostics(web), "fan2")
            return bool(counted["last_minute"]["timeouts"])

        await eventually(fan2_timed_out, every_s=0.1)
        found = await diagnostics(web)
        (bus,) = found["buses"]
        assert (bus["name"], bus["state"]) == ("line1", "open")
        assert bus["requests"] > 0
        assert bus["since_start"]["sent"] >= bus["last_minute"]["sent"] > 0
        pump = drive_counts(found, "pump1")
        assert pump["address"] == 1
        assert pump["since_start"]["exceptions"] == [
            {"code": "02H", "name": "illegal_data_address", "count": 1}
        ]
        assert pump["since_start"]["replies"] == pump["since_start"]["sent"]
        assert pump["since_start"]["timeouts"] == 0
        fan = drive_counts(found, "fan2")
        assert fan["since_start"]["timeouts"] >= fan["last_minute"]["timeouts"] > 0
        assert fan["since_start"]["failed"] > 0
        # Its retries began with a marker each: counted, for the bus and the drive.
        assert fan["since_start"]["resyncs"] > 0
        assert bus["since_start"]["resyncs"] == fan["since_start"]["resyncs"]
        total = bus["since_start"]
        assert total["timeouts"] == sum(d["since_start"]["timeouts"] for d in bus["drives"])
        assert total["sent"] == sum(d["since_start"]["sent"] for d in bus["drives"])
        # The client that asked is listed while connected, with its requests and errors.
        (listed,) = found["modbus_tcp"]["clients"]
        host, port = client.writer.get_extra_info("sockname")[:2]
        assert listed["address"] == f"{host}:{port}"
        assert (listed["requests"], listed["errors"], listed["tls"]) == (1, 1, False)
        assert listed["connected_since"].endswith("Z")
        await client.close()

        async def no_client() -> bool:
            return not (await diagnostics(web))["modbus_tcp"]["clients"]

        await eventually(no_client, every_s=0.1)
        assert found["mqtt"] is None


async def test_the_mqtt_session_with_its_broker_and_without(
    line: SimulatedLine, mosquitto: Mosquitto
) -> None:
    config = with_mqtt(console_config(line.path), mosquitto.host, mosquitto.port)
    async with running_gateway(config) as app, console_client(app) as web:
        assert (await web.login("victor", VIEWER_PASSWORD)).status == 200
        await connected(app)
        session = (await diagnostics(web))["mqtt"]
        assert session["broker"] == f"{mosquitto.host}:{mosquitto.port}"
        assert (session["protocol"], session["tls"], session["connected"]) == ("5", False, True)
        assert session["connected_since"].endswith("Z")
        assert (session["dropped"], session["last_error"]) == (0, None)
        assert session["queued"] >= 0
        mosquitto.stop()

        async def lost() -> bool:
            return not (await diagnostics(web))["mqtt"]["connected"]

        await eventually(lost, every_s=0.1)
        session = (await diagnostics(web))["mqtt"]
        assert session["connected_since"] is None
        assert session["last_error"]
        assert session["last_error_at"].endswith("Z")


async def test_after_a_reload_rebuilds_the_bridge_the_page_shows_the_new_session(
    line: SimulatedLine, mosquitto: Mosquitto
) -> None:
    """A reload that starts the MQTT bridge again: the page follows the new bridge, not the
    stopped one (which would say disconnected for good)."""
    config = with_mqtt(console_config(line.path), mosquitto.host, mosquitto.port)
    async with running_gateway(config) as app, console_client(app) as web:
        assert (await web.login("victor", VIEWER_PASSWORD)).status == 200
        await connected(app)
        assert config.mqtt is not None
        changed = config.mqtt.model_copy(update={"publish_interval_s": 30.0})
        plan = await app.reload(runtime_settings(config.model_copy(update={"mqtt": changed})))
        assert plan.restart_bridge
        await connected(app)
        session = (await diagnostics(web))["mqtt"]
        assert session["connected"] is True
        assert session["connects"] == 1  # the new bridge's first, not the stopped one's


async def test_a_healthy_3_1_1_link_shows_no_last_error(line: SimulatedLine) -> None:
    """The MQTT 5 attempt a 3.1.1-only broker refuses (CONNACK 132, "unsupported protocol
    version") is how the protocol is found, not an error: Diagnostics showed "Last error 132"."""
    broker = EmbeddedBroker("127.0.0.1", 0)  # speaks 3.1.1 only, as NATS and RabbitMQ do
    await broker.start()
    try:
        config = with_mqtt(console_config(line.path), broker.host, broker.port)
        async with running_gateway(config) as app, console_client(app) as web:
            assert (await web.login("victor", VIEWER_PASSWORD)).status == 200
            await connected(app)
            session = (await diagnostics(web))["mqtt"]
            assert (session["protocol"], session["connected"]) == ("3.1.1", True)
            assert (session["last_error"], session["last_error_at"]) == (None, None)
            assert (session["connects"], session["connect_failures"]) == (1, 0)
    finally:
        await broker.stop()


async def test_no_broker_there_is_a_last_error(line: SimulatedLine) -> None:
    config = with_mqtt(console_config(line.path), "127.0.0.1", free_port())
    async with running_gateway(config) as app, console_client(app) as web:
        assert (await web.login("victor", VIEWER_PASSWORD)).status == 200

        async def failed() -> bool:
            return bool((await diagnostics(web))["mqtt"]["last_error"])

        await eventually(failed, every_s=0.1)
        session = (await diagnostics(web))["mqtt"]
        assert session["connected"] is False
        assert session["connect_failures"] >= 1
        assert session["connects"] == 0


async def connected(app: Application) -> None:
    async def up() -> bool:
        return present(app.mqtt).connected.is_set()

    await eventually(up)


async def test_the_logs_recent_lines_with_a_level_filter(
    line: SimulatedLine, caplog: pytest.LogCaptureFixture
) -> None:
    """What the gateway logged while it ran, newest last, filtered by level; a bad level is a
    clear 400."""
    caplog.set_level(logging.INFO)  # the service's own default (`logging.level: info`)
    async with running_gateway(console_config(line.path)) as app, console_client(app) as web:
        assert (await web.login("victor", VIEWER_PASSWORD)).status == 200
        line.set_dead(2)  # the bus says so at WARNING once the drive goes offline

        async def offline_said() -> bool:
            found = await web.get_json("/api/log?level=warning")
            return any("drive 2 offline" in entry["message"] for entry in found["lines"])

        await eventually(offline_said, within_s=20, every_s=0.2)
        warnings = (await web.get_json("/api/log?level=warning"))["lines"]
        assert warnings
        assert {entry["level"] for entry in warnings} <= {"warning", "error"}
        assert all(entry["time"].endswith("Z") for entry in warnings)
        everything = (await web.get_json("/api/log?level=debug"))["lines"]
        assert len(everything) >= len(warnings)
        assert any(entry["logger"] == "gateway.console.feature" for entry in everything)
        last_two = (await web.get_json("/api/log?level=debug&limit=2"))["lines"]
        assert len(last_two) == 2
        async with web.session.get(f"{web.base}/api/log?level=loud") as response:
            assert response.status == 400
            assert "level must be one of" in await response.text()


async def test_the_running_configuration_for_operators_with_its_secrets_masked(
    line: SimulatedLine,
) -> None:
    config = with_mqtt(console_config(line.path), "127.0.0.1", free_port())
    assert config.mqtt is not None
    mqtt = config.mqtt.model_copy(update={"username": "plant", "password": "broker-secret-9"})
    config = config.model_copy(update={"mqtt": mqtt})
    async with running_gateway(config) as app:
        async with console_client(app) as viewer:
            assert (await viewer.login("victor", VIEWER_PASSWORD)).status == 200
            async with viewer.session.get(f"{viewer.base}/api/config") as refused:
                assert refused.status == 403
        async with console_client(app) as web:
            assert (await web.login("olga", OPERATOR_PASSWORD)).status == 200
            async with web.session.get(f"{web.base}/api/config") as response:
                assert response.status == 200
                text = await response.text()
            shown = (await web.get_json("/api/config"))["configuration"]
    # Every section, defaults filled in; the secrets only as "set".
    assert shown["buses"][0]["port"] == line.path
    assert shown["buses"][0]["drain_ms"] == 50  # a default the file left out
    assert shown["mqtt"]["username"] == "plant"
    assert shown["mqtt"]["password"] == "***"
    assert {user["password_hash"] for user in shown["console"]["users"]} == {"***"}
    assert "broker-secret-9" not in text
    assert "scrypt" not in text  # no hash of any user's password either


async def test_the_adapters_glitches_and_echoes_since_start(line: SimulatedLine) -> None:
    """What only /metrics said before: glitch bytes skipped and echoes, per bus."""
    line.set_adapter(glitch=b"\xff", echo=True)
    async with running_gateway(console_config(line.path)) as app, console_client(app) as web:
        assert (await web.login("victor", VIEWER_PASSWORD)).status == 200
        client = await TcpClient.connect(app.tcp.port)
        for _ in range(5):
            await client.read(1, 0x2100)
        await client.close()
        (bus,) = (await diagnostics(web))["buses"]
        counted = app.buses["line1"].line
        assert bus["line"]["glitch_bytes"] >= 5
        assert bus["line"]["echoes"] >= 5
        assert bus["line"]["glitch_bytes"] <= counted.garbage_bytes
        assert bus["line"]["echoes"] <= counted.echoes
