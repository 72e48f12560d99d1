"""Two gateways on a three-node NATS cluster (`mqtt.servers` listing every node), a dashboard's
persistent QoS 1 subscription on a node that stays up. The node a gateway uses is SIGKILLed and
stays down; later a gateway is SIGKILLed and restarted: every event still reaches the
subscriber, every drive's retained state is readable through every live node within 5 s of a
change, and the gateway whose node died publishes again through another node within
`RESUMED_WITHIN_S`.

What that bound is made of: NATS elects new leaders for the JetStream streams the dead node led
(MQTT sessions, QoS 1 messages, retained messages; 6-12 s measured here, most of it the raft
election timeouts), during which a node can't finish a QoS 1 publish; then one connection
attempt (at most `CONNECT_TIMEOUT_S`, 5 s) and the backoff (`reconnect_max_s`, 1 s here).
The gateways publish all but their events at QoS 0 and the events on a connection of their own
(`mqtt.publish_qos`, `mqtt.own_events_connection`): at QoS 1 a gateway on a live node was
thrown off by its node as well, 4 s after the death, and its states went stale meanwhile.
It holds because the gateway subscribes at QoS 0 (`SUBSCRIBE_QOS`): a QoS 1 subscription is a
replicated JetStream consumer, and with a node down creating a dozen of them outlasted every
attempt, so the gateway came back only with the node. The dashboards reading retained state
here subscribe at QoS 0 too, for the same reason: at QoS 1 each read made a replicated consumer,
and under a full suite's load the reads themselves went past the 5 s bound (the test ran on its
own then, `-m cluster`; it is in the suite again). Skipped where nats-server isn't installed.
"""

from __future__ import annotations

import asyncio
import contextlib
import signal
import sqlite3
import time
import uuid
from collections.abc import AsyncIterator, Iterator
from pathlib import Path
from typing import Any

import aiomqtt
import pytest

from gateway.instruments.simulator import SimulatedLine
from tests.support import RecordProperty, free_port
from tests.support.mosquitto import MqttProbe, mqtt_probe, unique_base_topic
from tests.support.mqtt_setup import simulated_line
from tests.support.nats import NatsNode, nats_cluster
from tests.support.processes import GatewayProcess

pytestmark = pytest.mark.cluster  # in the suite; alone with `pytest -m cluster`

RETAINED_WITHIN_S = 5.0
RESUMED_WITHIN_S = 25.0
ELECTIONS_S = 12.0
"""From a node's SIGKILL until the streams it led have new leaders (6-12 s measured here: module
doc). Retained messages are a JetStream stream: a change published before its new leader is
elected is stored only then, so the 5 s bound counts from a change made after it."""
"""From the SIGKILL of a gateway's node to its "online" through another node (module doc)."""
POLL = [{"name": "state", "start": 0x2100, "count": 3, "interval_ms": 300}]
"""The state words only: what changes with a fault; the cluster's nodes have CPU to spare."""
DRIVES = 16
"""Per gateway, as a cabinet's line has: 37 subscriptions, which at QoS 1 (a replicated
JetStream consumer each) kept a gateway from ever coming online, even with every node up."""
QUIET_POLL = [{"name": "state", "start": 0x2100, "count": 3, "interval_ms": 3000}]
"""The other drives': their topics are what matters here, not their traffic."""
FAULTS = (11, 12, 13)
"""Fault codes the drives are put through: each change is two events and a new retained state."""


def gateway_config(name: str, line: str, servers: list[NatsNode], base: str, store: Path) -> Any:
    return {
        "gateway_id": name,
        "modbus_tcp": {"host": "127.0.0.1", "port": free_port()},
        "buses": [{"name": "line1", "port": line, "baudrate": 115200}],
        "drives": [
            {"name": "pump1", "bus": "line1", "address": 1, "model": "gd350", "poll": POLL},
            *(
                {"name": f"fan{n}", "bus": "line1", "address": n, "poll": QUIET_POLL}
                for n in range(2, DRIVES + 1)
            ),
        ],
        "mqtt": {
            "servers": [node.address for node in servers],
            "base_topic": base,
            "homeassistant_discovery": False,
            "reconnect_max_s": 1.0,
            "publish_interval_s": 0.5,
            "keepalive_s": 5,
            # What the Operations page advises on NATS: a QoS 1 message the cluster can't store
            # yet (a stream electing its leader) makes the node close the connection it came on.
            "publish_qos": 0,
            "own_events_connection": True,
        },
        "storage": {"path": str(store)},
    }


class Gateway:
    """One gateway process on its own simulated line, that the test can kill and start again."""

    def __init__(self, config: dict[str, Any], line: SimulatedLine, directory: Path) -> None:
        self.config, self.line, self.directory = config, line, directory
        self.name: str = config["gateway_id"]
        self.base: str = config["mqtt"]["base_topic"]
        self.store = Path(config["storage"]["path"])
        self.process: GatewayProcess | None = None
        self.fault = 0

    def start(self) -> None:
        self.process = GatewayProcess(self.config, self.directory)

    def kill(self) -> None:
        assert self.process is not None
        self.process.signal(signal.SIGKILL)
        self.process.stop()  # reaps it, and closes its log
        self.process = None

    def stop(self) -> None:
        if self.process is not None:
            self.process.stop()
            self.process = None

    def set_fault(self, code: int) -> None:
        self.fault = code
        if code:
            self.line.inject_fault(1, code)
        else:
            self.line.clear_fault(1)

    def stored_ids(self, delivered_only: bool = False) -> set[int]:
        """The event ids in the gateway's store (read-only: it may be running)."""
        query = "SELECT id FROM events" + (" WHERE delivered = 1" if delivered_only else "")
        with contextlib.closing(sqlite3.connect(f"file:{self.store}?mode=ro", uri=True)) as db:
            return {row[0] for row in db.execute(query)}


@contextlib.contextmanager
def gateways(
    configs: list[tuple[dict[str, Any], SimulatedLine]], tmp: Path
) -> Iterator[list[Gateway]]:
    running = [Gateway(config, line, tmp) for config, line in configs]
    try:
        for gateway in running:
            gateway.start()
        yield running
    finally:
        for gateway in running:
            gateway.stop()


async def wait_until_serving(node: NatsNode, timeout_s: float = 20.0) -> None:
    """A node's MQTT listener answers before JetStream (its sessions' store) has a leader."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            async with aiomqtt.Client(node.host, node.port, identifier=uuid.uuid4().hex[:8]):
                return
        except aiomqtt.MqttError:
            if time.monotonic() > deadline:
                raise AssertionError(
                    f"{node.name} never took an MQTT client: {node.log()}"
                ) from None
            await asyncio.sleep(0.2)


async def retained_fault(node: NatsNode, topic: str) -> int | None:
    """The drive's retained state as a dashboard connecting to `node` now reads it."""
    try:
        async with mqtt_probe(node, topic, qos=0) as probe:
            received = await probe.wait_for(topic, timeout_s=1.0)
            return int(received.json()["fault_code"])
    except (AssertionError, aiomqtt.MqttError):
        return None


async def assert_retained_everywhere(everyone: list[Gateway], nodes: list[NatsNode]) -> None:
    """A change on every drive now; through every live node, each drive's retained state shows
    it within `RETAINED_WITHIN_S`."""
    for gateway in everyone:
        gateway.set_fault(FAULTS[(FAULTS.index(gateway.fault) + 1) % 3] if gateway.fault else 11)
    changed = time.monotonic()

    async def shows_it(node: NatsNode, gateway: Gateway) -> None:
        topic = f"{gateway.base}/pump1"
        while (seen := await retained_fault(node, topic)) != gateway.fault:
            late = time.monotonic() - changed
            assert late < RETAINED_WITHIN_S, (
                f"{node.name}: retained {topic} fault {seen}, not {gateway.fault}, {late:.1f} s on"
            )
            await asyncio.sleep(0.1)

    # Every node and gateway at once: asked one after another, the later ones would be charged
    # for the earlier ones' reads.
    await asyncio.gather(
        *(shows_it(node, gateway) for node in nodes if node.running for gateway in everyone)
    )


async def resumed(probe: MqttProbe, gateway: Gateway, mark: int, since: float) -> float:
    """Seconds from `since` to the gateway's next "online"."""
    try:
        await probe.wait_for(
            f"{gateway.base}/bridge/state",
            lambda s: s["state"] == "online",
            timeout_s=30,
            after=mark,
        )
    except AssertionError:
        log = gateway.process.log.text if gateway.process is not None else ""
        raise AssertionError(f"{gateway.name} did not come back online; its log:\n{log}") from None
    return time.monotonic() - since


@contextlib.asynccontextmanager
async def toggling(everyone: list[Gateway]) -> AsyncIterator[None]:
    """Faults raised and cleared on every drive all along: a steady stream of events."""

    async def toggle() -> None:
        while True:
            for gateway in everyone:
                gateway.set_fault(0 if gateway.fault else 12)
            await asyncio.sleep(0.4)

    task = asyncio.create_task(toggle(), name="toggle-faults")
    try:
        yield
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task


async def test_gateways_on_a_nats_cluster_ride_a_dead_node_and_a_dead_gateway(
    tmp_path: Path, record_property: RecordProperty
) -> None:
    site = unique_base_topic("site")
    with (
        nats_cluster(tmp_path) as nodes,
        simulated_line(tuple(range(1, DRIVES + 1))) as line_a,
        simulated_line(tuple(range(1, DRIVES + 1))) as line_b,
    ):
        for node in nodes:
            await wait_until_serving(node)
        n0, n1, n2 = nodes
        config_a = gateway_config("a", line_a.path, [n0, n1, n2], f"{site}/a", tmp_path / "a.db")
        config_b = gateway_config("b", line_b.path, [n1, n2, n0], f"{site}/b", tmp_path / "b.db")
        subscription = {"identifier": f"dashboard-{uuid.uuid4().hex[:6]}", "clean_session": False}
        events = f"{site}/+/bridge/event"
        async with mqtt_probe(n2, events, f"{site}/+/bridge/state", **subscription) as probe:
            with gateways([(config_a, line_a), (config_b, line_b)], tmp_path) as (a, b):
                for gateway in (a, b):
                    await probe.wait_for(
                        f"{gateway.base}/bridge/state",
                        lambda s: s["state"] == "online",
                        timeout_s=30,
                    )
                await assert_retained_everywhere([a, b], nodes)
                async with toggling([a, b]):
                    await asyncio.sleep(2)
                    # The node gateway A uses dies without a word, and stays dead to the end:
                    # A goes on through the other two.
                    mark, killed = len(probe.messages), time.monotonic()
                    n0.kill()
                    a_after_node = await resumed(probe, a, mark, killed)
                    assert a_after_node < RESUMED_WITHIN_S, (
                        f"gateway a took {a_after_node:.1f} s to publish again through a live node"
                    )
                    # The storm goes on until the dead node's streams have new leaders (CI saw
                    # a's retained state 5.1 s behind a change made 8.4 s after the death).
                    await asyncio.sleep(max(2.0, killed + ELECTIONS_S - time.monotonic()))
                # Checked between the storms, so each change is the test's own.
                await assert_retained_everywhere([a, b], nodes)
                async with toggling([a, b]):
                    await asyncio.sleep(1)
                    # Gateway B dies without a word, with events not yet out; it comes back.
                    mark, killed = len(probe.messages), time.monotonic()
                    b.kill()
                    b.start()
                    b_after_restart = await resumed(probe, b, mark, killed)
                    await asyncio.sleep(2)
                await assert_retained_everywhere([a, b], nodes)
                assert not n0.running

                # Every event each gateway stored reaches the subscriber; QoS 1 is at least
                # once, so one the broker had whose acknowledgement died with the node or the
                # gateway comes again (counted, not refused: dashboards de-duplicate by id).
                duplicates = {}
                for gateway in (a, b):
                    topic = f"{gateway.base}/bridge/event"
                    stored = gateway.stored_ids()
                    deadline = time.monotonic() + 10
                    while missing := stored - {m.json()["id"] for m in probe.on(topic)}:
                        assert time.monotonic() < deadline, (
                            f"{gateway.name}: never got {sorted(missing)[:20]}"
                        )
                        await asyncio.sleep(0.1)
                    assert len(stored) > 10
                    ids = [m.json()["id"] for m in probe.on(topic)]
                    duplicates[gateway.name] = (len(stored), len(ids) - len(set(ids)))
    record_property(
        "figure:NATS cluster failover",
        f"gateway a published again {a_after_node:.2f} s after its node's SIGKILL (the node "
        f"left down); gateway b {b_after_restart:.2f} s after its own SIGKILL and restart; "
        + "; ".join(
            f"{name}: {stored} events stored, all delivered, {again} delivered twice"
            for name, (stored, again) in duplicates.items()
        ),
    )
