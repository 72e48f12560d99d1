"""MQTT with TLS (a CA, a client certificate), the broker's username and password from the
environment, and monitoring only (`commands_enabled: false`), against a real Mosquitto that
demands all of it. A gateway missing any of it is turned away, and Modbus-TCP doesn't care."""

from __future__ import annotations

import asyncio
import logging
import subprocess
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml

from gateway.config import ENV_MQTT_PASSWORD, ENV_MQTT_USERNAME, parse_config
from gateway.errors import ConfigError, TlsSettingsError
from gateway.instruments.simulator import SimulatedLine
from gateway.mqtt.connection import tls_context
from gateway.settings import mqtt_settings
from tests.support import TcpClient, eventually, free_port, present, running_gateway
from tests.support.mosquitto import mqtt_probe, unique_base_topic
from tests.support.mqtt_setup import MQTT_LINE
from tests.support.processes import gateway_process
from tests.support.tls import PASSWORD, USERNAME, Certificates, TlsMosquitto, make_certificates

pytestmark = pytest.mark.line(**MQTT_LINE)

STATE_WORD_1 = 0x2100
STOPPED = 3


@pytest.fixture
def certificates(tmp_path: Path) -> Certificates:
    folder = tmp_path / "tls"
    folder.mkdir()
    return make_certificates(folder)


@pytest.fixture
def broker(tmp_path: Path, certificates: Certificates) -> Iterator[TlsMosquitto]:
    broker = TlsMosquitto(tmp_path, certificates)
    broker.start()
    try:
        yield broker
    finally:
        broker.stop()


def config_text(
    line: SimulatedLine, broker: TlsMosquitto, base: str, mqtt: dict[str, Any]
) -> dict[str, Any]:
    return {
        "gateway_id": "tls",
        "modbus_tcp": {"host": "127.0.0.1", "port": free_port()},
        "buses": [{"name": "line1", "port": line.path, "baudrate": 115200}],
        "drives": [{"name": "pump1", "bus": "line1", "address": 1, "model": "gd350"}],
        "mqtt": {
            "host": "127.0.0.1",
            "port": broker.port,
            "base_topic": base,
            "homeassistant_discovery": False,
            "reconnect_max_s": 1.0,
            **mqtt,
        },
    }


async def test_tls_with_client_certificate_and_credentials_from_the_environment(
    line: SimulatedLine, broker: TlsMosquitto, certificates: Certificates, tmp_path: Path
) -> None:
    base = unique_base_topic("tls")
    tls = {
        "tls": True,
        "ca_file": str(certificates.ca),
        "cert_file": str(certificates.client_cert),
        "key_file": str(certificates.client_key),
        "commands_enabled": False,  # monitoring only
    }
    config = config_text(line, broker, base, tls)  # no username or password in the file
    secrets = {ENV_MQTT_USERNAME: USERNAME, ENV_MQTT_PASSWORD: PASSWORD}
    credentials = {
        "tls_context": certificates.client_context(),
        "username": USERNAME,
        "password": PASSWORD,
    }
    with gateway_process(config, tmp_path, env=secrets) as gateway:
        gateway.wait_ready()
        async with mqtt_probe(broker, f"{base}/#", **credentials) as probe:
            await probe.wait_for(f"{base}/bridge/state", lambda s: s["state"] == "online")
            info = await probe.wait_for(f"{base}/bridge/info")
            assert info.json()["commands_enabled"] is False
            await probe.wait_for(f"{base}/pump1", lambda s: s["state"] == "stopped")
            # Monitoring only: every command refused with an answer, nothing reaches the drive.
            refused = await probe.request(
                f"{base}/pump1/set", {"command": "run_forward"}, f"{base}/pump1/set/response"
            )
            assert (refused["status"], refused["error"]) == ("error", "commands_disabled")
            refused = await probe.request(
                f"{base}/bridge/request/write_parameter",
                {"drive": "pump1", "parameter": "P00.11", "value": 1.0},
                f"{base}/bridge/response/write_parameter",
            )
            assert refused["error"] == "commands_disabled"
            # Reading is monitoring: answered.
            read = await probe.request(
                f"{base}/bridge/request/read_parameter",
                {"drive": "pump1", "parameter": "P00.11"},
                f"{base}/bridge/response/read_parameter",
            )
            assert read["status"] == "ok"
            assert read["data"]["raw"] == 100
        with line.lock:
            assert line.drives[1].parameter("P00.11") == 100
    assert f"u'{USERNAME}'" in broker.log()  # it logged in with the environment's username


@pytest.mark.parametrize("missing", ["client certificate", "right password"])
async def test_a_gateway_without_its_credentials_is_turned_away(
    line: SimulatedLine,
    broker: TlsMosquitto,
    certificates: Certificates,
    monkeypatch: pytest.MonkeyPatch,
    missing: str,
) -> None:
    tls: dict[str, Any] = {"tls": True, "ca_file": str(certificates.ca), "username": USERNAME}
    if missing == "client certificate":
        monkeypatch.setenv(ENV_MQTT_PASSWORD, PASSWORD)
    else:
        tls["cert_file"] = str(certificates.client_cert)
        tls["key_file"] = str(certificates.client_key)
        monkeypatch.setenv(ENV_MQTT_PASSWORD, "not-the-password")
    config = parse_config(yaml.safe_dump(config_text(line, broker, unique_base_topic(), tls)))
    async with running_gateway(config) as app:
        tcp = await TcpClient.connect(app.tcp.port)
        try:
            for _ in range(20):  # Modbus-TCP serves on, whatever MQTT does
                assert await tcp.read(1, STATE_WORD_1) == [STOPPED]
                await asyncio.sleep(0.05)  # SCADA's pace: a second of reads while MQTT fails
        finally:
            await tcp.close()
        assert not present(app.mqtt).connected.is_set()
    expected = "did not return a certificate" if missing == "client certificate" else "not auth"
    assert expected in broker.log()


def test_tls_settings_are_checked_at_load(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    ca = tmp_path / "ca.pem"
    ca.write_text("not checked here, only that it can be read")
    base = "buses: [{name: l, port: /dev/ttyUSB0}]\nmqtt: "

    def problems(mqtt: str) -> list[str]:
        with pytest.raises(ConfigError) as raised:
            parse_config(base + mqtt)
        return [f"{path}: {reason}" for path, reason in raised.value.problems]

    assert problems(f"{{ca_file: {ca}}}") == ["mqtt: ca_file given but tls is false: set tls: true"]
    assert problems(f"{{tls: true, key_file: {ca}}}") == [
        "mqtt: key_file without cert_file: give the client certificate too"
    ]
    assert problems(f"{{tls: true, ca_file: {tmp_path / 'missing.pem'}}}") == [
        f"mqtt.ca_file: {tmp_path / 'missing.pem'}: no such file"
    ]
    monkeypatch.setenv(ENV_MQTT_USERNAME, "from-environment")
    monkeypatch.setenv(ENV_MQTT_PASSWORD, "secret")
    mqtt = parse_config(base + "{username: from-file, tls: true}").mqtt
    assert mqtt is not None
    assert (mqtt.username, mqtt.password) == ("from-environment", "secret")


def test_an_encrypted_private_key_is_named_and_never_prompted_for(
    certificates: Certificates, tmp_path: Path
) -> None:
    """OpenSSL would ask for the passphrase on the terminal, blocking the service: instead the
    error names the keys and says what to do."""
    encrypted = tmp_path / "encrypted.key"
    encrypt = ["openssl", "pkey", "-in", str(certificates.client_key), "-out", str(encrypted)]
    subprocess.run(
        [*encrypt, "-aes256", "-passout", "pass:operator"], check=True, capture_output=True
    )
    mqtt = {"tls": True, "cert_file": str(certificates.client_cert), "key_file": str(encrypted)}
    config = parse_config(
        yaml.safe_dump({"buses": [{"name": "l", "port": "/dev/null"}], "mqtt": mqtt})
    )
    settings = mqtt_settings(config)
    assert settings is not None
    with pytest.raises(TlsSettingsError) as raised:
        tls_context(settings)
    assert raised.value.key == "mqtt.cert_file/mqtt.key_file"
    assert "encrypted" in raised.value.reason
    assert str(encrypted) in str(raised.value)


async def test_a_bad_tls_file_is_reported_once_and_retried_until_it_is_right(
    line: SimulatedLine,
    broker: TlsMosquitto,
    certificates: Certificates,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    caplog: pytest.LogCaptureFixture,
) -> None:
    """A CA file that can be read but holds no certificate passes validation (which only checks
    that the files are there). The bridge must say which key is wrong, once, and keep trying:
    when the right certificate is put in place, it connects without a restart."""
    ca = tmp_path / "ca-in-transit.pem"
    ca.write_text("-----BEGIN CERTIFICATE-----\nnot one\n-----END CERTIFICATE-----\n")
    tls = {
        "tls": True,
        "ca_file": str(ca),
        "cert_file": str(certificates.client_cert),
        "key_file": str(certificates.client_key),
        "username": USERNAME,
    }
    monkeypatch.setenv(ENV_MQTT_PASSWORD, PASSWORD)
    config = parse_config(yaml.safe_dump(config_text(line, broker, unique_base_topic(), tls)))

    def about_the_ca() -> list[logging.LogRecord]:
        return [r for r in caplog.records if "mqtt.ca_file" in r.getMessage()]

    with caplog.at_level(logging.DEBUG, logger="gateway.mqtt"):
        async with running_gateway(config) as app:
            # Said, then tried again, and again.
            await eventually(lambda: len(about_the_ca()) >= 3, within_s=10.0)
            assert not present(app.mqtt).connected.is_set()
            ca.write_bytes(certificates.ca.read_bytes())
            await asyncio.wait_for(present(app.mqtt).connected.wait(), 10)
    loud = [
        r.getMessage()
        for r in caplog.records
        if r.name.startswith("gateway.mqtt") and r.levelno >= logging.WARNING
    ]
    assert len(loud) == 1, loud
    assert "mqtt.ca_file" in loud[0]
    assert "no CA certificate" in loud[0]
