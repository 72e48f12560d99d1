"""A Sparkplug host's view for the tests: every `spBv1.0/#` message on a real Mosquitto, decoded
by Eclipse Tahu's JavaScript codec (npm `sparkplug-payload`, tests/peers/sparkplug_js), never by
the gateway's own code; NCMD and DCMD encoded by the same codec, as a host would send them."""

from __future__ import annotations

import asyncio
import base64
import contextlib
import json
import shutil
import subprocess
import time
from collections.abc import AsyncIterator, Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from tests.support.mosquitto import BrokerAddress, MqttProbe, mqtt_probe

PEER = Path(__file__).parent.parent / "peers" / "sparkplug_js"
Payload = dict[str, Any]


class TahuCodec:
    """`node codec.js`, one request and answer per line."""

    def __init__(self) -> None:
        node = shutil.which("node")
        if node is None or not (PEER / "node_modules" / "sparkplug-payload").is_dir():
            pytest.fail(
                "Tahu's JavaScript codec is missing: install nodejs and npm, then "
                "`. .ci/setup.sh; setup_node_peers` (bash .ci/test does both)"
            )
        self.process = subprocess.Popen(
            [node, str(PEER / "codec.js")],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )

    def _ask(self, line: str) -> Any:
        assert self.process.stdin is not None
        assert self.process.stdout is not None
        self.process.stdin.write(line + "\n")
        self.process.stdin.flush()
        answer = json.loads(self.process.stdout.readline())
        assert "error" not in answer, answer["error"]
        return answer

    def decode(self, data: bytes, birth_types: dict[int, str] | None = None) -> Payload:
        """`birth_types`: alias → datatype name, as the births declared them, for the metrics
        that come without one (DDATA), as a host decodes them."""
        request = "decode " + base64.b64encode(data).decode()
        if birth_types:
            request += " " + json.dumps(
                {str(a): t for a, t in birth_types.items()}, separators=(",", ":")
            )
        decoded: Payload = self._ask(request)
        return decoded

    def encode(self, payload: Payload) -> bytes:
        return base64.b64decode(self._ask("encode " + json.dumps(payload))["base64"])

    def close(self) -> None:
        if self.process.stdin is not None:
            self.process.stdin.close()
        self.process.wait(5)
        if self.process.stdout is not None:
            self.process.stdout.close()


@contextlib.contextmanager
def tahu_codec() -> Iterator[TahuCodec]:
    codec = TahuCodec()
    try:
        yield codec
    finally:
        codec.close()


@dataclass(frozen=True)
class Message:
    index: int
    topic: str
    retain: bool
    qos: int
    """As delivered to a QoS 1 subscription: the publisher's QoS where it was lower."""
    payload: Payload


def metrics(payload: Payload) -> dict[str, Any]:
    """A birth's metrics by name: {name: metric as Tahu decoded it}."""
    return {m["name"]: m for m in payload.get("metrics", []) if "name" in m}


def values(payload: Payload) -> dict[str, Any]:
    return {name: metric["value"] for name, metric in metrics(payload).items()}


class SparkplugHost:
    """A host application's view of one group: every message, decoded, in the order it came."""

    def __init__(self, probe: MqttProbe, codec: TahuCodec, group: str, node: str) -> None:
        self.probe = probe
        self.codec = codec
        self.group = group
        self.node = node
        self._decoded: dict[int, Payload] = {}

    def topic(self, kind: str, device: str | None = None) -> str:
        topic = f"spBv1.0/{self.group}/{kind}/{self.node}"
        return topic if device is None else f"{topic}/{device}"

    def decoded(self, index: int) -> Payload:
        if index not in self._decoded:
            message = self.probe.messages[index]
            types = None if "BIRTH" in message.topic else self.birth_types(index)
            self._decoded[index] = self.codec.decode(message.payload, types)
        return self._decoded[index]

    def birth_types(self, before: int) -> dict[int, str]:
        """Alias → datatype name as the births before message `before` declared them (aliases
        are unique across the edge node): what a host reads DDATA's values by."""
        prefix = f"spBv1.0/{self.group}/"
        types: dict[int, str] = {}
        for index, message in enumerate(self.probe.messages[:before]):
            if message.topic.startswith(prefix) and "BIRTH/" in message.topic and message.payload:
                for metric in self.decoded(index).get("metrics", []):
                    if "alias" in metric:
                        types[metric["alias"]] = metric["type"]
        return types

    def messages(self, after: int = 0) -> list[Message]:
        """Every Sparkplug message of this node (not STATE, not a cleared retained one)."""
        prefix = f"spBv1.0/{self.group}/"
        return [
            Message(i, m.topic, m.retain, m.qos, self.decoded(i))
            for i, m in enumerate(self.probe.messages[after:], after)
            if m.topic.startswith(prefix) and m.payload
        ]

    @property
    def mark(self) -> int:
        return len(self.probe.messages)

    async def wait_for(
        self,
        topic: str,
        match: Callable[[Payload], bool] = lambda _: True,
        after: int = 0,
        timeout_s: float = 10.0,
    ) -> Message:
        deadline = time.monotonic() + timeout_s
        while True:
            for message in self.messages(after):
                if message.topic == topic and match(message.payload):
                    return message
            if time.monotonic() > deadline:
                seen = [(m.topic, m.payload) for m in self.messages(after)][-10:]
                raise AssertionError(f"nothing matching on {topic} in {timeout_s} s; saw {seen}")
            await asyncio.sleep(0.02)

    async def command(
        self,
        kind: str,
        metrics: list[dict[str, Any]],
        device: str | None = None,
        age_s: float = 0.0,
        **publish: Any,
    ) -> None:
        """An NCMD or DCMD as Tahu's codec encodes it, stamped `age_s` ago."""
        stamp = int((time.time() - age_s) * 1000)
        data = self.codec.encode({"timestamp": stamp, "metrics": metrics})
        await self.probe.publish(self.topic(kind, device), data, **publish)


@contextlib.asynccontextmanager
async def sparkplug_host(
    broker: BrokerAddress, codec: TahuCodec, group: str, node: str, *more: str
) -> AsyncIterator[SparkplugHost]:
    """Subscribed to the group's topics (and `more`) before anything is published."""
    async with mqtt_probe(broker, f"spBv1.0/{group}/#", *more) as probe:
        yield SparkplugHost(probe, codec, group, node)
