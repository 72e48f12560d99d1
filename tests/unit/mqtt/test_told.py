"""What a standby keeps of what the consumers were told (`gateway.mqtt.told`): of two fault
events, the later by its time, not the later heard (a backlog handed over late)."""

from __future__ import annotations

import json

from gateway.mqtt.told import ToldConfig, ToldFaults

BASE = "plant"
EVENTS = f"{BASE}/bridge/event"


def fault(kind: str, code: int, at: str, box: str) -> bytes:
    data = {"drive": "pump", "fault_code": code}
    return json.dumps({"id": 1, "type": kind, "time": at, "data": data, "box": box}).encode()


def test_a_fault_event_handed_over_late_does_not_undo_a_newer_one() -> None:
    told = ToldFaults(BASE, ["pump"])
    told.take(EVENTS, fault("fault_cleared", 35, "2026-05-01T12:00:05.000Z", "b"))
    # Box a back as standby: its backlog, a trip from before the other box cleared it.
    told.take(EVENTS, fault("fault_raised", 35, "2026-05-01T12:00:01.000Z", "a"))
    assert told.faults == {"pump": 0}
    told.take(EVENTS, fault("fault_raised", 36, "2026-05-01T12:00:09.000Z", "b"))
    assert told.faults == {"pump": 36}


def test_the_other_box_s_configuration_is_heard_and_this_box_s_own_is_not() -> None:
    heard: list[tuple[str, dict[str, str]]] = []
    told = ToldConfig(BASE, "gw-a", lambda box, keys: heard.append((box, dict(keys))))
    assert told.topics == [f"{BASE}/bridge/redundancy/+/config"]
    keys = {"mqtt.base_topic": "0123456789ab"}
    payload = json.dumps({"box": "x", "keys": keys}).encode()
    told.take(f"{BASE}/bridge/redundancy/gw-a/config", payload)
    told.take(f"{BASE}/bridge/redundancy/gw-b", payload)  # its role: not this
    told.take(f"{BASE}/bridge/redundancy/gw-b/config", b"")  # cleared: nothing
    told.take(f"{BASE}/bridge/redundancy/gw-b/config", payload)
    assert heard == [("gw-b", keys)]
