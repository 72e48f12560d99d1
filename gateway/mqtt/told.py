"""What the active box has told MQTT consumers, as a standby hears it (`redundancy:` with
`mqtt:`): its drives' faults (`ToldFaults`), so that the box taking over raises no fault the
old active already reported, and reports every one it didn't (issue 48); and its Sparkplug
node's bdSeq (`ToldBirth`), so that the node's bdSeq counts on across the takeover; and, from
either box, the other box's configuration (`ToldConfig`: the digests of what both must share).

The two boxes have no store in common, so a takeover's memory must come from what the
consumers actually got: the broker. While it follows the line's master, the standby's role
connection (`gateway.mqtt.role`) subscribes to

    <base>/<drive>          retained: each drive's state as last published (`fault_code`)
    <base>/bridge/event     `fault_raised` / `fault_cleared` as they go out

and keeps, per drive, the fault code the consumers were last told: an event heard wins over
a state (events are what fault consumers act on; the retained state only stands in for a
drive with no fault event heard since this box started following), and of two events the
later by its `time`, not the later heard: a box that was away hands its backlog over late
(`gateway.mqtt.role`), after newer events of the other box's. At takeover the poller's
first poll of each drive compares with it (`Poller.open_faults`): a fault still there is "no
change"; one that started, or cleared, while nobody was told is raised, or cleared, once.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable, Mapping
from typing import Protocol

CONFIG_LEVEL = "config"
"""`<base>/bridge/redundancy/<box>/config`: that box's shared configuration's digests."""
BD_SEQ_KEY = "sparkplug_bd_seq"
"""In an active box's role announcement: the bdSeq its Sparkplug node was last born with."""


class Follower(Protocol):
    """Something a standby follows on its role connection."""

    @property
    def topics(self) -> list[str]: ...

    def take(self, topic: str, payload: bytes) -> None: ...


EVENT_KINDS = {"fault_raised": True, "fault_cleared": False}


class ToldFaults:
    """Each drive's fault code as the MQTT consumers were last told it (0: none)."""

    def __init__(self, base_topic: str, drives: Iterable[str]) -> None:
        self._states = {f"{base_topic}/{drive}": drive for drive in drives}
        self._events = f"{base_topic}/bridge/event"
        self._by_event: dict[str, tuple[str, int]] = {}
        """Drive → the latest fault event heard: its `time` (ISO, UTC: ordered as text), code."""
        self._by_state: dict[str, int] = {}
        self.heard = 0
        """Messages taken in (states and fault events)."""

    @property
    def topics(self) -> list[str]:
        return [*self._states, self._events]

    @property
    def faults(self) -> dict[str, int]:
        """Drive → the fault code told last: a fault event's, else the retained state's."""
        return {**self._by_state, **{drive: code for drive, (_, code) in self._by_event.items()}}

    def take(self, topic: str, payload: bytes) -> None:
        """One message from the broker (anything unreadable is no news)."""
        try:
            message = json.loads(payload)
        except ValueError:
            return
        if not isinstance(message, dict):
            return
        drive = self._states.get(topic)
        if drive is not None:
            code = message.get("fault_code")
            if isinstance(code, int) and not isinstance(code, bool):
                self._by_state[drive] = code
                self.heard += 1
            return
        if topic == self._events and message.get("type") in EVENT_KINDS:
            data = message.get("data")
            if not isinstance(data, dict) or data.get("drive") not in self._states.values():
                return
            code = data.get("fault_code")
            if not isinstance(code, int) or isinstance(code, bool):
                return
            at = message.get("time")
            at = at if isinstance(at, str) else ""
            drive = data["drive"]
            if drive in self._by_event and self._by_event[drive][0] > at:
                return  # older than the one told last (a backlog handed over late)
            self._by_event[drive] = (at, code if EVENT_KINDS[message["type"]] else 0)
            self.heard += 1


class ToldBirth:
    """The bdSeq the active box's Sparkplug node was last born with, from its retained role
    announcement (`<base>/bridge/redundancy/<box>`, `sparkplug_bd_seq`): retained, so a standby
    started after the birth knows it too. None: no other box's node heard born."""

    def __init__(self, base_topic: str, box: str) -> None:
        self._prefix = f"{base_topic}/bridge/redundancy/"
        self._own = f"{self._prefix}{box}"
        self.bd_seq: int | None = None

    @property
    def topics(self) -> list[str]:
        return [f"{self._prefix}+"]

    def take(self, topic: str, payload: bytes) -> None:
        if not topic.startswith(self._prefix) or topic == self._own:
            return
        try:
            message = json.loads(payload)
        except ValueError:
            return
        if not isinstance(message, dict) or message.get("role") != "active":
            return
        bd_seq = message.get(BD_SEQ_KEY)
        if isinstance(bd_seq, int) and not isinstance(bd_seq, bool):
            self.bd_seq = bd_seq


class ToldConfig:
    """The other box's configuration, as the digests of what both boxes must share
    (`gateway.config.peer.shared_digests`), retained by it on `<base>/bridge/redundancy/
    <box>/config`: each one heard is handed to `heard` (its box, key → digest), which compares it
    with this box's own (`gateway.redundancy.peer_config`)."""

    def __init__(
        self, base_topic: str, box: str, heard: Callable[[str, Mapping[str, str]], None]
    ) -> None:
        self._prefix = f"{base_topic}/bridge/redundancy/"
        self._box = box
        self._heard = heard

    @property
    def topics(self) -> list[str]:
        return [f"{self._prefix}+/{CONFIG_LEVEL}"]

    def take(self, topic: str, payload: bytes) -> None:
        if not topic.startswith(self._prefix) or not topic.endswith(f"/{CONFIG_LEVEL}"):
            return
        box = topic[len(self._prefix) : -len(CONFIG_LEVEL) - 1]
        if box == self._box or "/" in box:
            return
        try:
            message = json.loads(payload)
        except ValueError:
            return  # an empty retained message (the topic cleared) too
        keys = message.get("keys") if isinstance(message, dict) else None
        if isinstance(keys, dict) and all(isinstance(v, str) for v in keys.values()):
            self._heard(box, keys)
