"""The two boxes' running configurations compared (`gateway.config.peer`'s digests, and
`gateway.redundancy.peer_config.PeerConfig`): the keys named, never a value or a secret."""

from __future__ import annotations

import json
import logging
import warnings
from pathlib import Path
from typing import Any

import pytest

from gateway.config import GatewayConfig, load_config
from gateway.config.peer import shared_digests
from gateway.redundancy.peer_config import PeerConfig, differing

EXAMPLE = Path(__file__).resolve().parents[3] / "config" / "config.example.yaml"


def config(**changes: Any) -> GatewayConfig:
    """A pair's file: one drive polled on one line, with MQTT; `changes` over the top."""
    data: dict[str, Any] = {
        "buses": [{"name": "line1", "port": "/dev/ttyUSB0"}],
        "drives": [
            {"name": "pump", "bus": "line1", "address": 1, "model": "gd350"},
            {"name": "fan", "bus": "line1", "address": 2, "model": "gd350"},
        ],
        "mqtt": {"host": "broker", "username": "u", "password": "correct horse"},
        "redundancy": {"enabled": True, "box": "gw-a"},
        **changes,
    }
    return GatewayConfig.model_validate(data)


def test_the_digests_leave_out_each_box_s_own_keys_and_never_carry_a_value() -> None:
    digests = shared_digests(config())
    assert "drives[pump].address" in digests
    assert "redundancy.box" not in digests
    assert "buses[line1].port" not in digests  # each box's adapter path
    text = json.dumps(digests)
    assert "correct horse" not in text
    assert "broker" not in text
    assert all(len(value) == 12 for value in digests.values())


def test_a_secret_s_digest_says_only_whether_it_is_set() -> None:
    """A digest of a password on the broker could be guessed offline."""
    one = shared_digests(config())
    other = config(mqtt={"host": "broker", "username": "u", "password": "another"})
    assert differing(one, shared_digests(other)) == []
    unset = config(mqtt={"host": "broker", "username": "u"})
    assert differing(one, shared_digests(unset)) == ["mqtt.password"]


def test_the_keys_that_differ_are_named_and_an_item_only_one_box_has_is_one_key() -> None:
    here = shared_digests(config())
    buses = [{"name": "line1", "port": "/dev/ttyUSB1", "timeout_ms": 120}]
    drives = [{"name": "pump", "bus": "line1", "address": 1, "model": "gd350"}]
    there = shared_digests(config(buses=buses, drives=drives))
    assert differing(here, there) == ["buses[line1].timeout_ms", "drives[fan]"]
    assert differing(there, here) == ["buses[line1].timeout_ms", "drives[fan]"]


def test_the_example_file_s_access_registers_dump_as_the_file_writes_them() -> None:
    """A dump of the configuration (the console's, the digests, `check-config --peer`) says
    a register range as "2000H-2001H" or "P00.00-P99.99", read back the same, no warning."""
    loaded = load_config(str(EXAMPLE))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        dumped = loaded.model_dump(mode="json")
        shared_digests(loaded)
    registers = [rule["registers"] for rule in dumped["modbus_tcp"]["access"]]
    assert ["2000H-2001H"] in registers
    assert ["P00.00-P99.99"] in registers
    again = GatewayConfig.model_validate(dumped)
    assert again.modbus_tcp.access == loaded.modbus_tcp.access


def test_the_comparison_says_when_they_differ_and_when_alike_again(
    caplog: pytest.LogCaptureFixture,
) -> None:
    running = [config()]
    peer = PeerConfig(lambda: shared_digests(running[0]))
    assert peer.status() is None  # not heard yet
    peer.heard("gw-b", shared_digests(config()))
    status = peer.status()
    assert status is not None
    assert (status["peer"], status["differs"], status["count"]) == ("gw-b", [], 0)
    caplog.set_level(logging.INFO, "gateway.redundancy.peer_config")

    # This box reloaded with another broker account and base topic: said once, keys only.
    running[0] = config(mqtt={"host": "broker", "base_topic": "plant2"})
    peer.reloaded()
    peer.reloaded()
    warned = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warned) == 1
    assert "mqtt.base_topic" in warned[0].getMessage()
    assert "plant2" not in warned[0].getMessage()
    status = peer.status()
    assert status is not None
    assert status["differs"] == ["mqtt.base_topic", "mqtt.password", "mqtt.username"]
    since = status["since"]

    # The other box reloaded the same: alike again, said once.
    peer.heard("gw-b", shared_digests(running[0]))
    assert "runs this box's configuration again" in caplog.records[-1].getMessage()
    status = peer.status()
    assert status is not None
    assert status["count"] == 0
    assert status["since"] >= since
