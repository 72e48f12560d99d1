"""Running values through a broker outage: what the gateway polled while the broker was away
arrives once it is back, once, in the order polled, each with its time, over the JSON topics
(`<base>/<drive>/history`) and over Sparkplug B (DDATA metrics with `is_historical`, decoded by
Eclipse Tahu's codec), while the live values go on as before.

The outage is the broker unreachable for the gateway (a relay in front of Mosquitto cuts its
connections and closes its port for 3 s); the subscribers are connected to Mosquitto itself and
see everything. Two drives are polled every 0.3 s while their output current changes every
0.1 s, so every poll reads a new value."""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import json as json_text
import time
import uuid
from collections.abc import AsyncIterator, Iterator
from dataclasses import dataclass, field
from datetime import datetime

import pytest

from gateway.app import Application
from gateway.instruments.simulator import SimulatedLine
from gateway.profile.telemetry import Telemetry
from tests.support import eventually, running_gateway
from tests.support.mosquitto import (
    BrokerProxy,
    Mosquitto,
    Received,
    mqtt_probe,
    unique_base_topic,
)
from tests.support.mqtt_setup import mqtt_config, simulated_line
from tests.support.sparkplug import SparkplugHost, TahuCodec, metrics, sparkplug_host, tahu_codec

OUTAGE_S = 3.0
CURRENT = "output_current_a"
DRIVE_ADDRESSES = {"pump1": 1, "fan2": 2}


@pytest.fixture(scope="module")
def codec() -> Iterator[TahuCodec]:
    with tahu_codec() as codec:
        yield codec


@dataclass
class Polled:
    """What the gateway polled, as its other listeners saw it: per route, the output currents
    of the polls while that route's connection was away (the first poll of an outage, and each
    after it that read a new value), with their times."""

    app: Application
    since: float = field(default_factory=time.time)
    """From when it listened (what was kept before, at the start, is not this test's)."""
    away: dict[tuple[str, str], list[tuple[float, float]]] = field(default_factory=dict)
    live: dict[str, list[tuple[float, float]]] = field(default_factory=dict)
    """Drive → (monotonic time, current) of every poll."""
    _last: dict[tuple[str, str], float | None] = field(default_factory=dict)

    def state_updated(self, drive: str, telemetry: Telemetry) -> None:
        value = telemetry.get(CURRENT)
        if not isinstance(value, float):
            return
        self.live.setdefault(drive, []).append((time.monotonic(), value))
        mqtt, node = self.app.mqtt, self.app.sparkplug
        assert mqtt is not None
        assert node is not None
        for route, away in (
            ("json", not mqtt.connected.is_set()),
            ("sparkplug", not node.reaches_a_host()),
        ):
            key = (route, drive)
            if not away:
                self._last[key] = None
                continue
            if self._last.get(key) != value:
                self.away.setdefault(key, []).append((time.time(), value))
            self._last[key] = value

    def availability_changed(self, drive: str, online: bool) -> None:
        pass

    def drive_event(self, event: object) -> None:
        pass


async def ramp(line: SimulatedLine) -> None:
    """A new output current on each drive every 0.1 s (one decimal: no two polls alike)."""
    for step in itertools.count(1):
        for address in DRIVE_ADDRESSES.values():
            line.set_output_current(address, round(1.0 + step * 0.1 + address * 100, 1))
        await asyncio.sleep(0.1)


@contextlib.asynccontextmanager
async def running(task: asyncio.Task[None]) -> AsyncIterator[None]:
    try:
        yield
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task


async def test_values_polled_while_the_broker_is_away_arrive_once_in_order_with_their_time(
    mosquitto: Mosquitto, codec: TahuCodec
) -> None:
    base, group = unique_base_topic(), f"plant-{uuid.uuid4().hex[:8]}"
    with simulated_line() as line:
        async with BrokerProxy(mosquitto) as proxy:
            sparkplug = {"group_id": group, "edge_node_id": "cabinet-a"}
            config = mqtt_config(line.path, proxy, base, sparkplug=sparkplug)
            async with (
                sparkplug_host(mosquitto, codec, group, "cabinet-a") as host,
                mqtt_probe(mosquitto, f"{base}/+/history", f"{base}/+") as json,
                running_gateway(config) as app,
                running(asyncio.create_task(ramp(line))),
            ):
                for drive in DRIVE_ADDRESSES:
                    await host.wait_for(host.topic("DBIRTH", drive))
                assert app.mqtt is not None
                await asyncio.wait_for(app.mqtt.connected.wait(), 10)
                polled = Polled(app)  # from now on: both connections deliver
                app.poller.add_listener(polled)
                await asyncio.sleep(0.5)
                proxy.down()
                await asyncio.sleep(OUTAGE_S)
                await proxy.up()
                back = time.monotonic()
                await eventually(lambda: json_history_complete(json.messages, base, polled), 15)
                await eventually(lambda: sparkplug_history_complete(host, polled), 15)

    # JSON: every value polled during the outage, once, in order, with its time.
    for drive in DRIVE_ADDRESSES:
        expected = polled.away[("json", drive)]
        received = [s for s in json_history(json.messages, base, drive) if s[0] > polled.since]
        assert len(expected) >= OUTAGE_S / 0.3 - 2, expected  # polled at its own rate
        assert [v for _, v in received] == [v for _, v in expected]
        assert all(abs(r[0] - e[0]) < 0.05 for r, e in zip(received, expected, strict=True))

    # Sparkplug: historical DDATA metrics, by the birth's alias, each with its time.
    for drive in DRIVE_ADDRESSES:
        expected = polled.away[("sparkplug", drive)]
        received = [s for s in sparkplug_history(host, drive) if s[0] > polled.since]
        assert [v for _, v in received] == [v for _, v in expected]
        assert all(abs(r[0] - e[0]) < 0.05 for r, e in zip(received, expected, strict=True))

    # The live values were not held up: each polled after the return reached the JSON
    # subscriber within 1 s of its poll.
    states = [
        (m.at, m.json()[CURRENT])
        for m in json.messages
        if m.topic == f"{base}/pump1" and m.at > back and CURRENT in m.json()
    ]
    assert states, "no live state after the broker's return"
    polled_at = {value: at for at, value in polled.live["pump1"] if at > back}
    lags = [at - polled_at[value] for at, value in states if value in polled_at]
    assert lags, states
    assert max(lags) < 1.0, lags


def json_history(messages: list[Received], base: str, drive: str) -> list[tuple[float, float]]:
    """(time, output current) of every sample of `drive`'s history messages, as they came."""
    found = []
    for message in messages:
        if message.topic == f"{base}/{drive}/history":
            for sample in message.json().get("samples", []):
                if CURRENT in sample:
                    found.append((_epoch(sample["time"]), sample[CURRENT]))
    return found


def json_history_complete(messages: list[Received], base: str, polled: Polled) -> bool:
    return all(
        len([s for s in json_history(messages, base, drive) if s[0] > polled.since])
        >= len(polled.away.get(("json", drive), [(0.0, 0.0)]))
        for drive in DRIVE_ADDRESSES
    )


def sparkplug_history(host: SparkplugHost, drive: str) -> list[tuple[float, float]]:
    """(time, output current) of every historical metric of `drive`'s DDATA, as they came."""
    found = []
    births = [m for m in host.messages() if m.topic == host.topic("DBIRTH", drive)]
    aliases = {metrics(b.payload)[CURRENT]["alias"] for b in births}
    for message in host.messages():
        if message.topic != host.topic("DDATA", drive):
            continue
        for metric in message.payload["metrics"]:
            if metric.get("isHistorical") and metric.get("alias") in aliases:
                found.append((metric["timestamp"] / 1000, metric["value"]))
    return found


def sparkplug_history_complete(host: SparkplugHost, polled: Polled) -> bool:
    return all(
        len([s for s in sparkplug_history(host, drive) if s[0] > polled.since])
        >= len(polled.away.get(("sparkplug", drive), [(0.0, 0.0)]))
        for drive in DRIVE_ADDRESSES
    )


def _epoch(iso: str) -> float:
    return datetime.fromisoformat(iso.replace("Z", "+00:00")).timestamp()


async def test_values_polled_while_the_primary_host_is_offline_come_as_historical_ddata(
    mosquitto: Mosquitto, codec: TahuCodec
) -> None:
    """The specification's primary host: the edge node publishes only while its host is
    online, and "it would be better for the Edge Node to store data while the Host Application
    is offline" (Sparkplug 3.0, "Edge Node Session Establishment"): kept, then sent as
    historical DDATA after the next birth, in order, each with its time."""
    base, group = unique_base_topic(), f"plant-{uuid.uuid4().hex[:8]}"
    state_topic = "spBv1.0/STATE/scada"
    with simulated_line() as line:
        sparkplug = {"group_id": group, "edge_node_id": "cabinet-a", "primary_host_id": "scada"}
        config = mqtt_config(line.path, mosquitto, base, sparkplug=sparkplug)
        async with (
            sparkplug_host(mosquitto, codec, group, "cabinet-a") as host,
            mqtt_probe(mosquitto) as scada,
            running_gateway(config) as app,
            running(asyncio.create_task(ramp(line))),
        ):
            born_at = int(time.time() * 1000)
            await scada.publish(state_topic, host_state(True, born_at), retain=True)
            for drive in DRIVE_ADDRESSES:
                await host.wait_for(host.topic("DBIRTH", drive))
            polled = Polled(app)
            app.poller.add_listener(polled)
            await asyncio.sleep(0.5)
            await scada.publish(state_topic, host_state(False, born_at + 1), retain=True)
            death = await host.wait_for(host.topic("NDEATH"))
            await asyncio.sleep(2.0)
            await scada.publish(state_topic, host_state(True, born_at + 2), retain=True)
            await host.wait_for(host.topic("NBIRTH"), after=death.index)
            await eventually(lambda: sparkplug_history_complete(host, polled), 15)
            await scada.publish(state_topic, b"", retain=True)

    for drive in DRIVE_ADDRESSES:
        expected = polled.away[("sparkplug", drive)]
        received = [s for s in sparkplug_history(host, drive) if s[0] > polled.since]
        assert len(expected) >= 2.0 / 0.3 - 1, expected
        assert [v for _, v in received] == [v for _, v in expected]
        assert all(abs(r[0] - e[0]) < 0.05 for r, e in zip(received, expected, strict=True))


def host_state(online: bool, timestamp: int) -> str:
    return json_text.dumps({"online": online, "timestamp": timestamp})
