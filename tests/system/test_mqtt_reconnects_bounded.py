"""A broker that is killed and comes back, again and again, leaves nothing behind in the gateway:
after each reconnection as many MQTT clients, tasks and lanes as after the first (issue 45: the
soak's memory stepped at each broker restart; counted here, the steps were not the MQTT side's).
"""

from __future__ import annotations

import asyncio
import gc
import logging
from collections import Counter
from dataclasses import dataclass

import aiomqtt

from gateway.app import Application
from tests.support import eventually, present, running_gateway
from tests.support.mosquitto import Mosquitto, unique_base_topic
from tests.support.mqtt_setup import mqtt_config, simulated_line

WARM_RESTARTS = 2
RESTARTS = 6


@dataclass(frozen=True)
class Census:
    clients: int
    """aiomqtt clients alive after a full collection (the test's own: none)."""
    tasks: Counter[str]
    """The loop's tasks by name (aiomqtt's own, unnamed, as one kind)."""
    lanes: int


def census(app: Application) -> Census:
    forget_captured_records()
    gc.collect()
    clients = sum(1 for o in gc.get_objects() if isinstance(o, aiomqtt.Client))
    names = Counter(
        "unnamed" if task.get_name().startswith("Task-") else task.get_name()
        for task in asyncio.all_tasks()
        if task is not asyncio.current_task()
    )
    bridge = present(app.mqtt)
    node = present(app.sparkplug)
    return Census(clients, names, bridge.lanes.running + node.lanes.running)


def forget_captured_records() -> None:
    """pytest's log capture keeps every record, and a record of a lost connection keeps its
    exception, whose traceback keeps the failed client: not the gateway's (its handlers keep
    text, `gateway.console.log_tail`), so not counted."""
    for handler in logging.getLogger().handlers:
        records = getattr(handler, "records", None)
        if isinstance(records, list):
            records.clear()


async def restart(broker: Mosquitto, app: Application) -> None:
    bridge, node = present(app.mqtt), present(app.sparkplug)
    broker.stop()
    await eventually(
        lambda: not bridge.connected.is_set() and not node.connected.is_set(), what="lost"
    )
    await asyncio.sleep(1.5)  # a few failed attempts each: a client built for every one
    broker.start()
    await eventually(
        lambda: bridge.connected.is_set() and node.connected.is_set(),
        within_s=10,
        what="connected again",
    )
    await asyncio.sleep(0.5)  # the connection's work under way (births, history, events)


async def test_broker_restarts_leave_no_clients_or_tasks_behind(mosquitto: Mosquitto) -> None:
    base = unique_base_topic()
    with simulated_line() as line:
        sparkplug = {"group_id": "plant", "edge_node_id": base.replace("/", "-")}
        config = mqtt_config(line.path, mosquitto, base, sparkplug=sparkplug)
        async with running_gateway(config) as app:
            for _ in range(WARM_RESTARTS):
                await restart(mosquitto, app)
            first = census(app)
            for _ in range(RESTARTS):
                await restart(mosquitto, app)
            last = census(app)
    assert first.clients == last.clients == 2, "one for the bridge, one for the edge node"
    assert last.tasks == first.tasks
    assert last.lanes <= first.lanes + 1  # a drive's lane may be mid-poll-now, no more
