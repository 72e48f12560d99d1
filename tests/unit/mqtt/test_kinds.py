"""The registry of command kinds: a new `bridge/request/<op>` is one class, and it comes with its
topic, its drive's lane, the safety checks and the answer (a real gateway, Mosquitto, drives)."""

from __future__ import annotations

import time
from typing import Any

from gateway.app import Application
from gateway.mqtt.dispatcher import CommandKind
from gateway.mqtt.kinds import BRIDGE_REQUESTS, BridgeRequest
from gateway.mqtt.requests import Json, RegisterRead
from gateway.settings import runtime_settings
from tests.support import present, running_application
from tests.support.mosquitto import Mosquitto, mqtt_probe, unique_base_topic
from tests.support.mqtt_setup import mqtt_config, simulated_line

STOPPED = 3


class ReadStateWord(BridgeRequest):
    """What a new operation takes: its name, whether it writes, and what it does."""

    operation = "read_state_word"
    writes = False

    async def execute(self, payload: Json) -> Json:
        drive = self.context.commands.drive_named(payload)
        (word,) = await self.context.commands.read(drive, RegisterRead(0x2100, 1, None, False))
        return {"drive": drive.name, "state_word_1": word}


def test_every_bridge_request_has_its_own_operation() -> None:
    operations = [request.operation for request in BRIDGE_REQUESTS]
    assert operations == ["read_parameter", "write_parameter", "fault_history"]  # the README's


async def test_a_new_bridge_request_is_subscribed_checked_and_answered(
    mosquitto: Mosquitto,
) -> None:
    base = unique_base_topic()
    request_topic = f"{base}/bridge/request/read_state_word"
    response_topic = f"{base}/bridge/response/read_state_word"
    with simulated_line() as line:
        app = Application(runtime_settings(mqtt_config(line.path, mosquitto, base)))
        bridge = present(app.mqtt)
        kinds: dict[str, CommandKind] = dict(bridge.dispatcher.kinds)
        kinds[bridge.topics.bridge_request(ReadStateWord.operation)] = ReadStateWord(bridge.context)
        bridge.dispatcher.kinds = kinds
        async with mqtt_probe(mosquitto, f"{base}/#") as probe, running_application(app):
            # A client may act the moment it sees "online": the gateway listens by then.
            await probe.wait_for(f"{base}/bridge/state", lambda a: a["state"] == "online")
            answer: Any = await probe.request(request_topic, {"drive": "pump1"}, response_topic)
            assert answer["status"] == "ok"
            assert answer["data"] == {"drive": "pump1", "state_word_1": STOPPED}
            assert line.stats["requests"] > 0
            unknown: Any = await probe.request(request_topic, {"drive": "pump9"}, response_topic)
            assert unknown["error"] == "unknown_drive"
            payload = {"drive": "pump1", "time": time.time() - 3600}
            stale: Any = await probe.request(request_topic, payload, response_topic)
            assert stale["error"] == "stale"
