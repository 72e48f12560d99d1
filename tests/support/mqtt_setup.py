"""The whole gateway with MQTT on a simulated line, for the MQTT tests: short intervals, so each
test sees several polls within a second."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import Any

from gateway.config import GatewayConfig, MqttConfig
from gateway.instruments.simulator import SimulatedLine
from tests.support import gateway_config
from tests.support.mosquitto import BrokerAddress

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


MQTT_LINE: dict[str, Any] = {
    "addresses": (1, 2),
    "models": {1: "gd350", 2: "gd20"},
    "baudrate": 115200,
    "parity": "E",
    "wire_time": True,
    "response_delay_ms": 1.0,
}
"""The drives of `DRIVES` on a simulated line (`pytest.mark.line(**MQTT_LINE)` for the `line`
fixture)."""


@contextlib.contextmanager
def simulated_line(addresses: tuple[int, ...] = (1, 2)) -> Iterator[SimulatedLine]:
    """The MQTT tests' line (other drives are GD350s), for a test that starts more than one."""
    with SimulatedLine(**{**MQTT_LINE, "addresses": addresses}) as line:
        yield line
