"""The whole gateway with MQTT on a simulated line, for the MQTT tests: short intervals, so each
test sees several polls within a second."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import Any

from gateway.config import GatewayConfig, MqttConfig
from gateway.instruments.simulator import SimulatedLine
from tests.mosquitto import BrokerAddress
from tests.support import gateway_config

FAST_POLL = [
    {"name": "state", "start": 0x2100, "count": 3, "interval_ms": 150},
    {"name": "running", "start": 0x3000, "count": 12, "interval_ms": 300},
]
DRIVES: list[dict[str, Any]] = [
    {"name": "pump1", "address": 1, "model": "gd350", "poll": FAST_POLL},
    {"name": "fan2", "address": 2, "model": "gd20", "poll": FAST_POLL},
]


def mqtt_config(
    line_path: str,
    broker: BrokerAddress,
    base_topic: str,
    gateway_id: str = "test",
    drives: list[dict[str, Any]] | None = None,
    bus: dict[str, Any] | None = None,
    **mqtt: Any,
) -> GatewayConfig:
    config = gateway_config(line_path, drives if drives is not None else DRIVES, **(bus or {}))
    settings = MqttConfig.model_validate(
        {
            "host": broker.host,
            "port": broker.port,
            "base_topic": base_topic,
            "publish_interval_s": 5,
            "reconnect_max_s": 1.0,
            **mqtt,
        }
    )
    return config.model_copy(update={"mqtt": settings, "gateway_id": gateway_id})


@contextlib.contextmanager
def simulated_line(addresses: tuple[int, ...] = (1, 2)) -> Iterator[SimulatedLine]:
    models = {1: "gd350", 2: "gd20"}
    line = SimulatedLine(
        addresses=addresses,
        models={a: models.get(a, "gd350") for a in addresses},
        baudrate=115200,
        parity="E",
        wire_time=True,
        response_delay_ms=1.0,
    )
    line.start()
    try:
        yield line
    finally:
        line.stop()
