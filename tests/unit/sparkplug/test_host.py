"""The primary host's STATE: online and offline by its JSON, an older STATE ignored, anything
else ignored (and logged) rather than taken for either."""

from __future__ import annotations

import json

from gateway.sparkplug.host import PrimaryHost


def state(online: object, timestamp: object) -> bytes:
    return json.dumps({"online": online, "timestamp": timestamp}).encode()


def test_online_then_offline_and_stale_states_ignored() -> None:
    host = PrimaryHost("scada")
    assert not host.online
    assert host.update(state(True, 1000))
    assert host.online
    assert not host.update(state(False, 999)), "older than the newest seen: stale"
    assert host.online
    assert host.update(state(False, 1000)), "the will carries the birth's timestamp"
    assert not host.online
    assert not host.update(state(False, 2000))  # no change


def test_what_is_not_a_state_is_ignored() -> None:
    host = PrimaryHost("scada")
    host.update(state(True, 5))
    for payload in (b"OFFLINE", b"{}", state("false", 6), state(False, "6"), b"[1]"):
        assert not host.update(payload)
        assert host.online
