"""What a takeover carries from one box to the other (issue 48's second step), with two real
gateway processes on one simulated line (`simulate --masters 2`) and a real Mosquitto.

What a site checks: a drive's fault reported by the old active is not reported again by the
new one (its MQTT consumers see one `fault_raised` for one trip), and a fault that starts after
the takeover is reported once, by the new active; the active's USB adapter unplugged, it says
so in its fault file (Keepalived's track_file) a second later, leaves the line, and the other
box's first request is on the line within 3 s of the unplug.
"""

from __future__ import annotations

import asyncio
import signal
import time
import uuid
from pathlib import Path

import pytest
from asyncua import Client, ua

from gateway.opcua.address_space import NAMESPACE
from gateway.redundancy.roles import PORTLESS_S
from tests.support import free_port
from tests.support.mosquitto import Mosquitto, MqttProbe, mqtt_probe
from tests.support.redundancy import TAKEOVER_BOUND_S, Box, frames, pair_broker, start_pair
from tests.support.redundancy import boxes as boxes  # the fixtures
from tests.support.redundancy import line as line
from tests.support.shared_line import SharedLine
from tests.support.sparkplug import sparkplug_host, tahu_codec, values


def raised(probe: MqttProbe, events: str, code: int, after: int = 0) -> int:
    """`fault_raised` events of drive pump with `code` seen on MQTT (from message `after`)."""
    return sum(
        1
        for message in probe.messages[after:]
        if message.topic == events
        and message.json()["type"] == "fault_raised"
        and message.json()["data"]["fault_code"] == code
    )


async def test_a_fault_reported_by_the_old_active_is_not_reported_again_by_the_new_one(
    line: SharedLine, boxes: list[Box], tmp_path: Path, mosquitto: Mosquitto
) -> None:
    base, events, broker = pair_broker(mosquitto)
    async with mqtt_probe(mosquitto, events, f"{base}/pump") as probe:
        old, new = await asyncio.to_thread(start_pair, boxes, line.paths, tmp_path, mqtt=broker)
        await probe.wait_for(f"{base}/pump", lambda s: s["fault_code"] == 0)

        line.command("fault 1 35")  # the drive trips while box a is active
        await probe.wait_for(events, lambda e: e["type"] == "fault_raised")
        await asyncio.sleep(0.5)  # box b hears it too, through the broker
        old.gateway.process.send_signal(signal.SIGKILL)
        await asyncio.to_thread(old.gateway.process.wait, 5)
        mark = len(probe.messages)
        await asyncio.to_thread(new.notified, "MASTER")
        await asyncio.to_thread(new.wait_role, "active", 5.0)
        # The new active polls the tripped drive and publishes its state: still fault 35...
        await probe.wait_for(f"{base}/pump", lambda s: s["fault_code"] == 35, after=mark)
        await asyncio.sleep(1.0)  # five polls more
        # ...and raises nothing: the consumers were told of this trip once, by box a.
        assert raised(probe, events, 35) == 1
        told = [m.json()["type"] for m in probe.messages[mark:] if m.topic == events]
        assert [kind for kind in told if kind.startswith("fault")] == []

        # A fault that starts after the takeover: reported once, by box b.
        start = time.monotonic()
        line.command("clear 1")
        await probe.wait_for(events, lambda e: e["type"] == "fault_cleared", after=mark)
        line.command("fault 1 36")
        await probe.wait_for(events, lambda e: e["data"].get("fault_code") == 36, after=mark)
        await asyncio.sleep(1.0)
        assert raised(probe, events, 36, after=mark) == 1
        assert raised(probe, events, 35, after=mark) == 0
        # Each box numbers its events on its own: they say whose they are.
        boxes_told = {
            (m.json()["data"].get("fault_code"), m.json()["box"]) for m in probe.on(events)
        }
        assert {(35, "a"), (36, "b")} <= boxes_told
        assert time.monotonic() - start < 10
    assert line.stats()["collisions"] == 0


def test_the_active_s_adapter_unplugged_it_fails_keepalived_s_check_and_leaves_the_line(
    line: SharedLine, boxes: list[Box], tmp_path: Path
) -> None:
    # Box a's adapter by its udev link, as a site names it (/dev/serial/by-id/...): the link goes
    # when the adapter is pulled out (and a pty's number may be another's a moment later).
    adapter = tmp_path / "usb-adapter-a"
    adapter.symlink_to(line.paths[0])
    old, new = start_pair(boxes, (str(adapter), line.paths[1]), tmp_path)
    assert not old.check_fails()
    assert not new.check_fails()
    assert not old.says_unfit()
    assert not new.says_unfit()
    adapter.unlink()  # box a's USB adapter pulled out: its link and its port gone
    line.command("unplug-master 1")
    unplugged = time.monotonic()
    # Its fault file says 1 once the port has been gone PORTLESS_S: Keepalived reads it at once.
    while not old.says_unfit():
        assert time.monotonic() - unplugged < PORTLESS_S + 1.0, old.status()
        time.sleep(0.01)
    unfit_s = time.monotonic() - unplugged
    # Keepalived: box a in FAULT (standby), box b MASTER at once (box a's priority-0 advert):
    # b takes the line once silent.
    old.notified("FAULT")
    new.notified("MASTER")
    while frames(line)[1] == 0:
        assert time.monotonic() - unplugged < TAKEOVER_BOUND_S + 2.0, line.stats()
        time.sleep(0.01)
    first_request_s = time.monotonic() - unplugged
    assert PORTLESS_S - 0.1 < unfit_s < PORTLESS_S + 0.5, unfit_s
    assert first_request_s < TAKEOVER_BOUND_S, first_request_s
    # The track script fails too (the slower way, and the one for a dead gateway).
    assert old.check_fails()
    status = old.wait_role("standby", 2.0)
    assert status["fit"] is False
    assert "no port open on any line" in old.gateway.log.text
    assert old.health()["status"] == "degraded"
    assert not new.check_fails()
    assert not new.says_unfit()
    new.wait_role("active", 1.0)
    assert new.read_state()[:2] == bytes([0x03, 0x02])
    assert line.stats()["collisions"] == 0
    print(f"unfit {unfit_s:.2f} s, first request {first_request_s:.2f} s after the unplug")


def test_a_stopping_gateway_tells_keepalived_at_once_and_a_started_one_that_it_is_fit(
    line: SharedLine, boxes: list[Box], tmp_path: Path
) -> None:
    boxes.append(box := Box("b", line.paths[1], tmp_path, "standby"))
    said(box, "0\n")  # fit: written as its role machine starts
    box.gateway.process.terminate()  # systemctl stop: the box can't be the master from now
    box.gateway.process.wait(5)
    assert box.fault_file.read_text() == "1\n"  # Keepalived: FAULT, without the track script
    box.stop()
    boxes[0] = Box("b", line.paths[1], tmp_path, "standby")  # started again: fit
    said(boxes[0], "0\n")


def said(box: Box, value: str) -> None:
    """Wait (up to 2 s) for `box`'s fault file to say `value`."""
    deadline = time.monotonic() + 2.0
    while not (box.fault_file.exists() and box.fault_file.read_text() == value):
        assert time.monotonic() < deadline, box.gateway.log.text[-2000:]
        time.sleep(0.01)


async def test_opc_ua_is_off_on_a_standby_and_served_by_the_active(
    line: SharedLine, boxes: list[Box], tmp_path: Path
) -> None:
    port = free_port()
    opcua = {"enabled": True, "port": port, "anonymous": True, "security": ["None"]}
    standby = await asyncio.to_thread(Box, "b", line.paths[1], tmp_path, "standby", opcua=opcua)
    boxes.append(standby)
    # A standby's OPC UA port is closed: a client is told "not here" at once, and moves on.
    with pytest.raises(ConnectionRefusedError):
        await asyncio.open_connection("127.0.0.1", port)
    await asyncio.to_thread(standby.ask, "active")  # the line is silent: it takes it
    await asyncio.to_thread(standby.wait_role, "active", 5.0)
    # OPC UA starts beside: its address space built, and (its first start) its certificate
    # made, seconds on a busy machine that Modbus-TCP doesn't wait for.
    deadline = time.monotonic() + 20
    while True:
        try:
            async with Client(f"opc.tcp://127.0.0.1:{port}", timeout=4) as client:
                ns = await client.get_namespace_index(NAMESPACE)
                state = await client.get_node(ua.NodeId("pump.state", ns)).read_data_value()
                if state.StatusCode.is_good():  # polled by this box, now the active one
                    break
        except (OSError, TimeoutError, ua.UaError):
            assert time.monotonic() < deadline
            await asyncio.sleep(0.2)
    # Back to standby: the port closes again.
    await asyncio.to_thread(standby.ask, "standby")
    await asyncio.to_thread(standby.wait_role, "standby", 5.0)
    with pytest.raises(ConnectionRefusedError):
        await asyncio.open_connection("127.0.0.1", port)


async def test_sparkplug_s_node_moves_to_the_new_active_with_a_new_nbirth_its_bdseq_counting_on(
    line: SharedLine, boxes: list[Box], tmp_path: Path, mosquitto: Mosquitto
) -> None:
    group = f"plant-{uuid.uuid4().hex[:8]}"
    _, _, broker = pair_broker(
        mosquitto, sparkplug={"group_id": group, "edge_node_id": "cabinet-a"}
    )
    with tahu_codec() as codec:
        async with sparkplug_host(mosquitto, codec, group, "cabinet-a") as host:
            old = await asyncio.to_thread(Box, "a", line.paths[0], tmp_path, "active", mqtt=broker)
            boxes.append(old)
            # The standby's node is silent: one node, born by the active box only.
            new = await asyncio.to_thread(Box, "b", line.paths[1], tmp_path, "standby", mqtt=broker)
            boxes.append(new)
            born = await host.wait_for(host.topic("NBIRTH"))
            await host.wait_for(host.topic("DBIRTH", "pump"), after=born.index)
            first = values(born.payload)["bdSeq"]
            await asyncio.sleep(1.0)  # box b hears box a's role announcement, with its bdSeq
            assert [m.topic for m in host.messages() if "NBIRTH" in m.topic] == [born.topic]

            old.gateway.process.send_signal(signal.SIGKILL)
            await asyncio.to_thread(old.gateway.process.wait, 5)
            # Box a's will: the NDEATH of its birth's bdSeq, the node dead for the host.
            death = await host.wait_for(host.topic("NDEATH"), after=born.index)
            assert values(death.payload)["bdSeq"] == first
            await asyncio.to_thread(new.notified, "MASTER")
            reborn = await host.wait_for(host.topic("NBIRTH"), after=death.index)
            # Box b's node: a new NBIRTH whose bdSeq is the next one, as the node's next CONNECT
            # (a late NDEATH of box a's, its network gone, never matches it), then its drives.
            assert values(reborn.payload)["bdSeq"] == (first + 1) % 256
            assert values(reborn.payload)["Node Info/gateway_id"] == "pair"
            await host.wait_for(host.topic("DBIRTH", "pump"), after=reborn.index)
            births = [m for m in host.messages() if m.topic == host.topic("NBIRTH")]
            assert len(births) == 2
