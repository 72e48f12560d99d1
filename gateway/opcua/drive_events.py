"""A drive's events as OPC UA events: a fault raised or cleared, a limit passed or back inside,
the drive lost or back, for a SCADA's alarm list or a historian's event log.

Each is a `DriveEventType` (our subtype of BaseEventType, NodeId `ns=2;s=DriveEventType`) with
three fields of its own besides BaseEventType's:

    Kind        the gateway's word for it, as the console and MQTT say it (`fault_raised`...)
    FaultCode   the fault code (0: the event is not a fault's)
    FaultName   its short name from the profile's fault table ("OL1"; "" when it has none)

and BaseEventType's `Message` in words (the fault's code, name and text, the profile's fault
table's: `fault_words`, the owner the log and the console read too), `Severity` (`SEVERITY`),
`SourceNode` and `SourceName` the drive, `Time` when the poller noticed it.

Plain events, not conditions (AlarmConditionType): the drive owns its fault's state (it stays
tripped until a reset, whatever a client acknowledges), asyncua has no Acknowledge or Confirm
method of its own to carry it, and every SCADA alarm list makes its alarms from events with a
severity. A client learns what is active now from the `fault_code` variable.

An event is notified on the drive, its bus, the gateway and the Server object (each an
EventNotifier, joined by HasNotifier): a client subscribes where it likes, and one fault is one
EventId wherever it is seen.
"""

from __future__ import annotations

import datetime
import uuid
from collections.abc import Mapping, Sequence
from typing import Any, Final

from asyncua import Node, Server, ua

from gateway.event_log import fault_words
from gateway.poller import DriveEvent
from gateway.poller.drive_state import EventKind

EVENT_TYPE: Final = "DriveEventType"
SEVERITY: Final[Mapping[EventKind, int]] = {
    EventKind.FAULT_RAISED: 800,  # a trip: the drive has stopped its motor
    EventKind.DRIVE_OFFLINE: 600,  # no answer: nothing is known of it any more
    EventKind.ALARM_RAISED: 300,  # a warning: a value beyond the limit set for it
    EventKind.FAULT_CLEARED: 200,
    EventKind.ALARM_CLEARED: 200,
    EventKind.DRIVE_ONLINE: 200,
}
"""OPC UA's 1..1000 (Part 5: 801-1000 high, 601-800 medium high, 201-400 medium low, 1-200
low), as Ignition and the others map it to their alarm priorities."""
FIELDS: Final = (
    ("Kind", ua.VariantType.String, ""),
    ("FaultCode", ua.VariantType.UInt16, 0),
    ("FaultName", ua.VariantType.String, ""),
)


def message(event: DriveEvent) -> str:
    """The event in words, as the gateway's log says it."""
    data = event.data
    if event.kind is EventKind.FAULT_RAISED:
        return f"fault raised: {fault_words(data)}"
    if event.kind is EventKind.FAULT_CLEARED:
        return f"fault cleared: {fault_words(data)}"
    if event.kind is EventKind.ALARM_RAISED:
        return (
            f"{data.get('point')} beyond its {data.get('limit')} limit "
            f"{data.get('threshold')}: {data.get('value')}"
        )
    if event.kind is EventKind.ALARM_CLEARED:
        return f"{data.get('point')} back inside its {data.get('limit')} limit: {data.get('value')}"
    if event.kind is EventKind.DRIVE_OFFLINE:
        return "offline: no answer"
    return "online again"


class DriveEvents:
    """The event type, the notifiers, and each drive event triggered on them."""

    def __init__(self, server: Server, namespace: int) -> None:
        self.server = server
        self.ns = namespace
        self.chains: dict[str, tuple[ua.NodeId, ...]] = {}
        """Each drive's notifiers: the drive, its bus, the gateway, the Server object."""
        self._event: Any = None
        self._isession: Any = None

    async def install(self) -> None:
        """The event type, and the generator whose event object is reused for every event."""
        base = self.server.nodes.base_event_type
        kind = await base.add_object_type(
            ua.NodeId(EVENT_TYPE, self.ns), ua.QualifiedName(EVENT_TYPE, self.ns)
        )
        for name, variant, initial in FIELDS:
            field = await kind.add_property(
                ua.NodeId(f"{EVENT_TYPE}.{name}", self.ns),
                ua.QualifiedName(name, self.ns),
                ua.Variant(initial, variant),
            )
            await field.set_modelling_rule(True)
        generator = await self.server.get_event_generator(kind, self.server.nodes.server)
        self._event = generator.event
        self._isession = generator.isession

    async def notifier(self, parent: Node, child: Node) -> None:
        """`child` an EventNotifier, its events heard on `parent` too."""
        await child.set_event_notifier([ua.EventNotifier.SubscribeToEvents])
        await parent.add_reference(child.nodeid, ua.ObjectIds.HasNotifier)

    def drive(self, name: str, chain: Sequence[ua.NodeId]) -> None:
        self.chains[name] = (*chain, self.server.nodes.server.nodeid)

    async def trigger(self, event: DriveEvent) -> None:
        chain = self.chains.get(event.drive)
        if chain is None or self._event is None:
            return
        fields = self._event
        at = datetime.datetime.fromtimestamp(event.at, datetime.UTC)
        fields.EventId = ua.Variant(uuid.uuid4().bytes, ua.VariantType.ByteString)
        fields.Time = at
        fields.ReceiveTime = datetime.datetime.now(datetime.UTC)
        fields.SourceNode = chain[0]
        fields.SourceName = event.drive
        fields.Severity = SEVERITY[event.kind]
        fields.Message = ua.LocalizedText(message(event))
        fields.Kind = str(event.kind)
        code = event.data.get("fault_code")
        fields.FaultCode = code if isinstance(code, int) and event.kind.startswith("fault") else 0
        fields.FaultName = str(event.data.get("fault_name", "")) if fields.FaultCode else ""
        for node_id in chain:
            fields.emitting_node = node_id
            await self._isession.subscription_service.trigger_event(fields)
