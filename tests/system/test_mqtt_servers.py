"""`mqtt.servers`: a list of brokers (a cluster's nodes) tried in turn. The broker in use is told
in `bridge/state`, the metric `invt_gateway_mqtt_server_info` and the diagnostics; when it goes,
the gateway moves to the next one and publishes there."""

from __future__ import annotations

import subprocess
from pathlib import Path

from gateway.config import GatewayConfig, MqttConfig
from gateway.mqtt.metrics import MqttMetrics
from tests.support import eventually, gateway_config, present, running_gateway
from tests.support.mosquitto import Mosquitto, mqtt_probe, running_mosquitto, unique_base_topic
from tests.support.mqtt_setup import DRIVES, simulated_line
from tests.support.processes import check_config

GOOD = """
buses: [{name: line1, port: /dev/serial/by-id/usb-FTDI-line1}]
drives: [{name: pump1, bus: line1, address: 1}]
"""


def check_mqtt(tmp_path: Path, mqtt: str) -> subprocess.CompletedProcess[str]:
    """`check-config` of the file above with this `mqtt` section."""
    return check_config(tmp_path, GOOD + f"mqtt: {mqtt}\n")


def test_servers_and_host_both_given_is_refused_naming_the_keys(tmp_path: Path) -> None:
    result = check_mqtt(tmp_path, "{servers: ['127.0.0.1:1883'], host: 10.0.0.1}")
    assert result.returncode == 3
    assert "servers and host both given" in result.stderr


def test_a_server_that_is_not_host_port_is_refused(tmp_path: Path) -> None:
    result = check_mqtt(tmp_path, "{servers: ['10.0.0.1:1883', 'node2']}")
    assert result.returncode == 3
    assert "mqtt.servers" in result.stderr
    assert "'node2' is not host:port" in result.stderr


def test_the_one_server_form_and_a_list_both_load(tmp_path: Path) -> None:
    assert check_mqtt(tmp_path, "{host: 10.0.0.1, port: 1884}").returncode == 0
    assert check_mqtt(tmp_path, "{servers: ['10.0.0.1:1883', '[::1]:1884']}").returncode == 0


def servers_config(line_path: str, brokers: list[Mosquitto], base: str) -> GatewayConfig:
    config = gateway_config(line_path, DRIVES)
    mqtt = MqttConfig.model_validate(
        {
            "servers": [f"{b.host}:{b.port}" for b in brokers],
            "base_topic": base,
            "publish_interval_s": 0.5,
            "reconnect_max_s": 1.0,
        }
    )
    return config.model_copy(update={"mqtt": mqtt, "gateway_id": "failover"})


def server_info(metrics: MqttMetrics) -> dict[str, float]:
    family = next(f for f in metrics.collect() if f.name == "invt_gateway_mqtt_server_info")
    return {sample.labels["server"]: sample.value for sample in family.samples}


async def test_the_gateway_moves_to_the_next_server_when_its_broker_goes(tmp_path: Path) -> None:
    base = unique_base_topic()
    with (
        running_mosquitto(tmp_path) as first,
        running_mosquitto(tmp_path) as second,
        simulated_line() as line,
    ):
        name_1, name_2 = f"{first.host}:{first.port}", f"{second.host}:{second.port}"
        config = servers_config(line.path, [first, second], base)
        async with running_gateway(config) as app:
            metrics = MqttMetrics(present(app.mqtt))
            async with mqtt_probe(first, f"{base}/#") as probe:
                state = await probe.wait_for(f"{base}/bridge/state")
                assert state.json()["state"] == "online"
                assert state.json()["server"] == name_1
            assert present(app.mqtt).status().broker == name_1
            assert server_info(metrics) == {name_1: 1.0, name_2: 0.0}

            first.stop()  # SIGKILL: the connection drops
            async with mqtt_probe(second, f"{base}/#") as probe:
                state = await probe.wait_for(f"{base}/bridge/state", timeout_s=10)
                assert state.json() == {
                    "state": "online",
                    "server": name_2,
                    "gateway_id": "failover",
                    "client_id": "invt-gateway-failover",
                }
                mark = len(probe.messages)
                await probe.wait_for(f"{base}/pump1", after=mark)  # publishing there, live
            assert present(app.mqtt).status().broker == name_2
            await eventually(
                lambda: present(app.mqtt).status().connected, what="connected to the second"
            )
            assert server_info(metrics) == {name_1: 0.0, name_2: 1.0}
