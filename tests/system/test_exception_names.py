"""Each device's exception in its maker's words, everywhere the gateway says it.

INVT gives 04H-09H meanings of its own (06H: "data frame error"); ABB's drives, meters and
other devices follow the Modbus standard (06H: "server device busy"). On one line, an INVT
drive, an ABB drive and a generic device all answer 06H while they are busy (the simulator's
`refuse`): MQTT's answer, the console's answer to a command, its traffic monitor and its
diagnostics name each one's 06H as its maker does.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Iterator
from typing import Any

import pytest

from gateway.config import GatewayConfig
from gateway.instruments.simulator import SimulatedLine
from tests.support import present, running_gateway
from tests.support.console_support import OPERATOR_PASSWORD, USERS, console_client
from tests.support.mosquitto import Mosquitto, mqtt_probe, unique_base_topic

BUSY = 0x06
WORDS = {
    "pump1": "data_frame_error",  # INVT's 06H
    "fan2": "server_device_busy",  # ABB follows the standard
    "meter3": "server_device_busy",  # and so does a device the gateway only carries
}


@contextlib.contextmanager
def busy_line() -> Iterator[SimulatedLine]:
    """A GD350 at 1, an ACS580 at 2 and a device at 3, all answering 06H to everything."""
    with SimulatedLine(
        addresses=[1, 2, 3], models={2: "acs580"}, baudrate=115200, response_delay_ms=1
    ) as line:
        for address in (1, 2, 3):
            line.refuse(address, BUSY)
        yield line


def configuration(line: SimulatedLine, broker: Mosquitto, base: str) -> GatewayConfig:
    drives: list[dict[str, Any]] = [
        {"name": "pump1", "bus": "line1", "address": 1, "model": "gd350"},
        {"name": "fan2", "bus": "line1", "address": 2, "model": "acs580"},
        {"name": "meter3", "bus": "line1", "address": 3, "model": "generic"},
    ]
    return GatewayConfig.model_validate(
        {
            "modbus_tcp": {"host": "127.0.0.1", "port": 0},
            "buses": [{"name": "line1", "port": line.path, "baudrate": 115200, "retries": 0}],
            "drives": drives,
            "mqtt": {"host": broker.host, "port": broker.port, "base_topic": base},
            "console": {"enabled": True, "host": "127.0.0.1", "port": 0, "users": USERS},
        }
    )


async def test_mqtt_answers_each_devices_exception_in_its_makers_words(
    mosquitto: Mosquitto,
) -> None:
    base = unique_base_topic()
    with busy_line() as line:
        config = configuration(line, mosquitto, base)
        async with running_gateway(config) as app, mqtt_probe(mosquitto, f"{base}/#") as probe:
            await asyncio.wait_for(present(app.mqtt).connected.wait(), 5)
            for drive, words in WORDS.items():
                answer = await probe.request(
                    f"{base}/{drive}/set",
                    {"register": 1, "raw": 1},  # a register write: every profile takes it
                    f"{base}/{drive}/set/response",
                )
                assert (answer["status"], answer["error"]) == ("error", words), answer
                assert answer["exception_code"] == BUSY
                assert answer["message"].startswith(f"06H {words.replace('_', ' ')}")


@pytest.mark.parametrize(("drive", "words"), [("pump1", "data frame error"), ("fan2", "busy")])
async def test_the_console_says_a_refused_command_in_the_makers_words(
    mosquitto: Mosquitto, drive: str, words: str
) -> None:
    base = unique_base_topic()
    with busy_line() as line:
        config = configuration(line, mosquitto, base)
        async with running_gateway(config) as app, console_client(app) as web:
            await web.login("olga", OPERATOR_PASSWORD)
            status, body = await web.post(f"/api/drives/{drive}/command", {"command": "stop"})
            assert status == 502, body
            assert body["error"].startswith("drive refused: 06H"), body
            assert words in body["error"], body
            # The diagnostics page counts each drive's exceptions by its maker's name.
            shown = await web.get_json("/api/diagnostics")
            (line_shown,) = shown["buses"]
            counted = {
                d["drive"]: {e["name"] for e in d["since_start"]["exceptions"]}
                for d in line_shown["drives"]
            }
            assert counted["pump1"] >= {"data_frame_error"}, counted
            assert counted["fan2"] >= {"server_device_busy"}, counted
            assert "data_frame_error" not in counted["fan2"] | counted["meter3"], counted
            # A line of several makers counts in the standard's words.
            line_names = {e["name"] for e in line_shown["since_start"]["exceptions"]}
            assert line_names == {"server_device_busy"}, line_shown
