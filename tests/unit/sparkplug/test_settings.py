"""`mqtt.sparkplug` from the file: names checked at load (one topic level each), the edge node
named after the gateway unless given, and errors that name the key."""

from __future__ import annotations

import pytest

from gateway.config import parse_config
from gateway.errors import ConfigError
from gateway.settings import runtime_settings
from gateway.settings.mqtt import SparkplugSettings

FILE = """
gateway_id: cabinet-a
buses: [{{name: line1, port: /dev/null}}]
drives: [{{name: pump1, bus: line1, address: 1}}]
mqtt:
  sparkplug: {sparkplug}
"""


def settings(sparkplug: str) -> SparkplugSettings | None:
    mqtt = runtime_settings(parse_config(FILE.format(sparkplug=sparkplug))).mqtt
    assert mqtt is not None
    return mqtt.sparkplug


def test_edge_node_is_the_gateway_unless_named() -> None:
    assert settings("{group_id: plant}") == SparkplugSettings("plant", "cabinet-a", None)
    assert settings(
        "{group_id: plant, edge_node_id: line-2, primary_host_id: scada}"
    ) == SparkplugSettings("plant", "line-2", "scada")
    assert settings("{group_id: plant, enabled: false}") is None
    assert settings("null") is None


@pytest.mark.parametrize(
    ("sparkplug", "key"),
    [
        ("{edge_node_id: x}", "mqtt.sparkplug.group_id"),
        ("{group_id: a/b}", "mqtt.sparkplug.group_id"),
        ("{group_id: plant, edge_node_id: 'line+2'}", "mqtt.sparkplug.edge_node_id"),
        ("{group_id: plant, primary_host_id: 'scada#'}", "mqtt.sparkplug.primary_host_id"),
        ("{group_id: plant, primary_host: scada}", "mqtt.sparkplug.primary_host"),
    ],
)
def test_bad_names_are_refused_naming_the_key(sparkplug: str, key: str) -> None:
    with pytest.raises(ConfigError) as refused:
        settings(sparkplug)
    assert key in str(refused.value)
