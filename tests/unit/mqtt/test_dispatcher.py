"""The dispatcher on a real Mosquitto: each topic to its kind, in its lane, every sender answered
(busy when the lane is full, internal_error when the kind fails), and the receive loop never
held up by a kind that waits."""

from __future__ import annotations

import asyncio
import contextlib
import json
import uuid
from collections.abc import AsyncIterator, Mapping
from dataclasses import dataclass, field

import aiomqtt

from gateway.mqtt.dispatcher import CommandKind, Dispatcher, Incoming, transaction
from gateway.mqtt.lanes import Lanes
from gateway.mqtt.requests import Json, dump, ok_response
from gateway.mqtt.stats import BridgeStats
from tests.support.mosquitto import Mosquitto, MqttProbe, mqtt_probe, unique_base_topic

MAX_WAITING = 2


@dataclass
class Echo:
    """Answers with what it got, after `gate` opens (set at once unless a test holds it)."""

    response_topic: str | None
    lane_name: str
    gate: asyncio.Event = field(default_factory=asyncio.Event)
    command: bool = True
    ran: list[bytes] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.gate.set()

    def lane(self, message: Incoming) -> str | None:
        return self.lane_name

    async def run(self, client: aiomqtt.Client, message: Incoming) -> None:
        await self.gate.wait()
        self.ran.append(message.payload)
        if self.response_topic is not None:
            response = ok_response(
                transaction(message.payload), {"got": json.loads(message.payload)}
            )
            await client.publish(self.response_topic, dump(response), qos=1)


class Broken:
    """A kind with a bug."""

    command = True

    def __init__(self, response_topic: str) -> None:
        self.response_topic = response_topic

    def lane(self, message: Incoming) -> str | None:
        return "broken"

    async def run(self, client: aiomqtt.Client, message: Incoming) -> None:
        raise RuntimeError("a bug")


async def answer(client: aiomqtt.Client, topic: str, response: Json) -> None:
    with contextlib.suppress(aiomqtt.MqttError):
        await client.publish(topic, dump(response), qos=1)


@contextlib.asynccontextmanager
async def dispatching(
    broker: Mosquitto, kinds: Mapping[str, CommandKind], stats: BridgeStats
) -> AsyncIterator[Lanes]:
    """A gateway-side client that subscribes to the kinds' topics and runs the dispatcher."""
    lanes = Lanes(MAX_WAITING)
    dispatcher = Dispatcher(kinds, lanes, answer, stats)
    client = aiomqtt.Client(broker.host, broker.port, identifier=f"gw-{uuid.uuid4().hex[:8]}")
    async with client:
        await client.subscribe([(topic, 1) for topic in dispatcher.topics])
        receiving = asyncio.create_task(dispatcher.run(client))
        try:
            yield lanes
        finally:
            await lanes.close(1.0)
            receiving.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await receiving


async def test_each_topic_goes_to_its_kind_and_is_answered_on_its_response_topic(
    mosquitto: Mosquitto,
) -> None:
    base = unique_base_topic()
    one = Echo(f"{base}/one/response", "one")
    two = Echo(f"{base}/two/response", "two")
    stats = BridgeStats()
    kinds = {f"{base}/one": one, f"{base}/two": two}
    async with dispatching(mosquitto, kinds, stats), mqtt_probe(mosquitto, f"{base}/#") as probe:
        answer_one = await probe.request(f"{base}/one", {"n": 1}, f"{base}/one/response")
        answer_two = await probe.request(f"{base}/two", {"n": 2}, f"{base}/two/response")
        assert answer_one["status"] == "ok"
        assert answer_one["data"]["got"]["n"] == 1
        assert answer_two["data"]["got"]["n"] == 2
        assert (len(one.ran), len(two.ran)) == (1, 1)
    assert stats.ignored == 0


async def test_a_full_lane_answers_busy_and_holds_up_no_other_lane(mosquitto: Mosquitto) -> None:
    base = unique_base_topic()
    held = Echo(f"{base}/held/response", "held")
    held.gate.clear()  # its first message runs and waits: the next ones queue behind it
    free = Echo(f"{base}/free/response", "free")
    stats = BridgeStats()
    kinds = {f"{base}/held": held, f"{base}/free": free}
    async with dispatching(mosquitto, kinds, stats), mqtt_probe(mosquitto, f"{base}/#") as probe:
        for n in range(1 + MAX_WAITING):  # one running, MAX_WAITING waiting: the lane is full
            await probe.publish(f"{base}/held", {"n": n, "transaction": f"t{n}"})
        busy = await probe.request(f"{base}/held", {"n": 9}, f"{base}/held/response")
        assert busy["status"] == "error"
        assert busy["error"] == "busy"
        assert busy["exception_code"] == 0x0A
        # Another kind's lane is served meanwhile.
        assert (await probe.request(f"{base}/free", {"n": 1}, f"{base}/free/response"))["data"]
        held.gate.set()
        for n in range(1 + MAX_WAITING):
            await probe.wait_for(
                f"{base}/held/response", lambda r, n=n: r["transaction"] == f"t{n}"
            )
    assert stats.busy == 1
    assert len(held.ran) == 1 + MAX_WAITING


async def test_a_kind_that_fails_answers_internal_error_and_the_next_message_is_handled(
    mosquitto: Mosquitto,
) -> None:
    base = unique_base_topic()
    kinds: dict[str, CommandKind] = {
        f"{base}/broken": Broken(f"{base}/broken/response"),
        f"{base}/echo": Echo(f"{base}/echo/response", "echo"),
    }
    async with (
        dispatching(mosquitto, kinds, BridgeStats()),
        mqtt_probe(mosquitto, f"{base}/#") as probe,
    ):
        failed = await probe.request(f"{base}/broken", {}, f"{base}/broken/response")
        assert failed["status"] == "error"
        assert failed["error"] == "internal_error"
        assert (await probe.request(f"{base}/echo", {"n": 3}, f"{base}/echo/response"))["data"]


async def test_a_kind_without_a_lane_is_looked_at_on_the_receive_loop_and_queues_nothing(
    mosquitto: Mosquitto,
) -> None:
    base = unique_base_topic()

    class Checked(Echo):
        def lane(self, message: Incoming) -> str | None:
            self.ran.append(message.payload)  # looked at on the receive loop, nothing queued
            return None

    checked = Checked(None, "never")
    echo = Echo(f"{base}/echo/response", "echo")
    stats = BridgeStats()
    kinds = {f"{base}/checked": checked, f"{base}/echo": echo}
    async with dispatching(mosquitto, kinds, stats) as lanes, mqtt_probe(mosquitto) as probe:
        probe_client: MqttProbe = probe
        await probe_client.client.subscribe(f"{base}/echo/response", qos=1)
        await probe_client.publish(f"{base}/checked", {"n": 1})
        # Messages from one publisher arrive in order: once the echo is answered, the checked
        # message has been dispatched.
        await probe_client.request(f"{base}/echo", {"n": 2}, f"{base}/echo/response")
        assert checked.ran == [b'{"n": 1}']
        assert lanes.waiting("never") == 0
    assert stats.ignored == 0
