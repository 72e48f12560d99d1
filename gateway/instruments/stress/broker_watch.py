"""An MQTT client that notes each time the gateway says it is online (`<base>/bridge/state`).

It keeps reconnecting while the broker is down, like any dashboard would, so the first "online"
after a broker restart measures how long the gateway took to come back to it.
"""

from __future__ import annotations

import asyncio
import json
import time
import uuid

import aiomqtt

RETRY_S = 0.1


class OnlineWatch:
    def __init__(self, host: str, port: int, base_topic: str) -> None:
        self.host = host
        self.port = port
        self.topic = f"{base_topic}/bridge/state"
        self.online_at: list[float] = []
        """monotonic() of every "online" seen (retained or live)."""

    def first_online_after(self, moment: float) -> float | None:
        return next((at for at in self.online_at if at > moment), None)

    async def run(self) -> None:
        while True:
            client = aiomqtt.Client(
                self.host, self.port, identifier=f"stress-watch-{uuid.uuid4().hex[:8]}"
            )
            try:
                async with client:
                    await client.subscribe(self.topic, qos=1)
                    async for message in client.messages:
                        if _state(message.payload) == "online":
                            self.online_at.append(time.monotonic())
            except aiomqtt.MqttError:
                await asyncio.sleep(RETRY_S)


def _state(payload: object) -> str | None:
    try:
        data = json.loads(payload if isinstance(payload, bytes | str) else b"")
    except ValueError:
        return None
    return data.get("state") if isinstance(data, dict) else None
