"""The address space: Objects → the gateway → each bus → each drive and device, its polled
values as variables, its commands as methods.

NodeIds are strings in the namespace `NAMESPACE` (its index is the server's NamespaceArray's
to tell; with this server, 2), made of the configuration's names only, so they stay the same
across restarts and reloads:

    gateway                          the gateway (browse name: its gateway_id)
    bus:<bus>                        a bus (an RS-485 line)
    <drive>                          a drive or device (its name is unique in the gateway)
    <drive>.<key>                    a value, keyed as in MQTT's state (output_frequency_hz...)
    <drive>.<key>.EngineeringUnits   its unit (UNECE)
    <drive>.<key>.EURange            its range, where the model knows it
    <drive>.run_state                the state as a MultiStateDiscrete (EnumStrings: its words)
    <drive>.<Method>                 RunForward, Stop... (CamelCase of the profile's commands)
    <drive>.Parameters.<Pxx.yy>      a parameter (`parameters`)
    DriveEventType                   the type of its events (`drive_events`)

A drive sits under its bus in the tree, but its NodeIds don't name the bus: moving a drive to
another line keeps every client's configured items.
"""

from __future__ import annotations

import datetime
from collections.abc import Awaitable, Callable, Sequence
from dataclasses import dataclass, field
from typing import Final

from asyncua import Node, Server, ua

from gateway.mqtt.commands import CommandDrive
from gateway.opcua.command_path import WriteTarget
from gateway.opcua.values import (
    ANY,
    RUN_STATES,
    engineering_units,
    status_value,
    variant_type,
)
from gateway.settings import DriveSettings
from gateway.sparkplug.metrics import unit_of

NAMESPACE: Final = "urn:invt-gateway:drives"
NOT_SERVED: Final = frozenset({"last_seen"})
"""The SourceTimestamp says when."""
SETPOINT: Final = "set_frequency_hz"
"""The set frequency as read back; written, it is the `frequency_hz` of a `/set`."""
RUN_STATE: Final = "run_state"
"""The `state` word's number (`values.run_state`), beside the word itself."""
FREQUENCIES: Final = frozenset({SETPOINT, "output_frequency_hz"})
"""Their EURange: 0 to the drive's maximum frequency (P00.03) as read at start."""

TAKES_FREQUENCY: Final = frozenset({"run_forward", "run_reverse"})
"""The methods with a set-point argument: MQTT's `{"command": ..., "frequency_hz": ...}`."""
FREQUENCY_ARGUMENT: Final = ua.Argument(
    Name="FrequencyHz",
    DataType=ua.NodeId(ua.ObjectIds.Double),
    ValueRank=-1,
    Description=ua.LocalizedText(
        "set frequency (Hz) written before the run, within the drive's limits; a client that "
        "may leave it out runs at the present set point"
    ),
)

MethodCall = Callable[..., Awaitable[ua.CallMethodResult]]


@dataclass(slots=True)
class DriveNodes:
    """One drive's variables: key → (NodeId, its type), and what each shows now."""

    name: str
    variables: dict[str, tuple[ua.NodeId, ua.VariantType]] = field(default_factory=dict)
    shown: dict[str, ua.DataValue] = field(default_factory=dict)


def method_name(command: str) -> str:
    """run_forward → RunForward."""
    return "".join(part.capitalize() for part in command.split("_"))


class AddressSpaceBuilder:
    """Adds the gateway's nodes to a server once, at start."""

    def __init__(self, server: Server, namespace: int, commands_enabled: bool) -> None:
        self.server = server
        self.ns = namespace
        self.commands_enabled = commands_enabled
        self.targets: dict[ua.NodeId, WriteTarget] = {}
        """The variables whose writes go to a drive."""

    def node_id(self, text: str) -> ua.NodeId:
        return ua.NodeId(text, self.ns)

    def name(self, text: str) -> ua.QualifiedName:
        return ua.QualifiedName(text, self.ns)

    async def gateway(self, gateway_id: str) -> Node:
        objects = self.server.nodes.objects
        return await objects.add_object(self.node_id("gateway"), self.name(gateway_id))

    async def bus(self, gateway: Node, name: str) -> Node:
        return await gateway.add_object(self.node_id(f"bus:{name}"), self.name(name))

    async def drive(
        self,
        bus: Node,
        drive: DriveSettings,
        command_drive: CommandDrive,
        call: Callable[[CommandDrive, str], MethodCall],
        max_frequency_hz: float | None = None,
    ) -> DriveNodes:
        node = await bus.add_object(self.node_id(drive.name), self.name(drive.name))
        nodes = DriveNodes(drive.name)
        now = datetime.datetime.now(datetime.UTC)
        waiting = status_value(ua.StatusCodes.BadWaitingForInitialData, now)
        profile = drive.profile
        writable = {p.name for p in profile.typed_points if p.writable}
        for key in sorted(profile.telemetry_keys - NOT_SERVED):
            kind = variant_type(profile, key)
            variable = await self._variable(node, f"{drive.name}.{key}", key, kind)
            await self._units(variable, f"{drive.name}.{key}", unit_of(profile, key))
            if key in FREQUENCIES and max_frequency_hz is not None:
                await self._range(variable, f"{drive.name}.{key}", 0.0, max_frequency_hz)
            nodes.variables[key] = (variable.nodeid, kind)
            await self.server.write_attribute_value(variable.nodeid, waiting)
            takes_setpoint = key == SETPOINT and bool(profile.commands)
            if self.commands_enabled and (key in writable or takes_setpoint):
                await variable.set_writable()
                shape = "point" if key in writable else "setpoint"
                self.targets[variable.nodeid] = WriteTarget(command_drive, key, shape)
        if "state" in profile.telemetry_keys and RUN_STATE not in profile.telemetry_keys:
            state = await self._run_state(node, drive.name)
            nodes.variables[RUN_STATE] = (state.nodeid, ua.VariantType.UInt32)
            await self.server.write_attribute_value(state.nodeid, waiting)
        for command in profile.commands if self.commands_enabled else ():
            await self._method(node, drive.name, command, call(command_drive, command))
        return nodes

    async def _variable(self, parent: Node, text: str, key: str, kind: ua.VariantType) -> Node:
        datatype = ua.NodeId(ua.ObjectIds.BaseDataType) if kind is ANY else None
        initial = ua.Variant(None) if kind is ANY else ua.Variant(_zero(kind), kind)
        return await parent.add_variable(
            self.node_id(text), self.name(key), initial, varianttype=kind, datatype=datatype
        )

    async def _units(self, variable: Node, text: str, symbol: str) -> None:
        units = engineering_units(symbol)
        if units is None:
            return
        await variable.add_property(
            self.node_id(f"{text}.EngineeringUnits"),
            ua.QualifiedName("EngineeringUnits", 0),
            ua.Variant(units, ua.VariantType.ExtensionObject),
            datatype=ua.NodeId(ua.ObjectIds.EUInformation),
        )

    async def _range(self, variable: Node, text: str, low: float, high: float) -> None:
        await variable.add_property(
            self.node_id(f"{text}.EURange"),
            ua.QualifiedName("EURange", 0),
            ua.Variant(ua.Range(Low=low, High=high), ua.VariantType.ExtensionObject),
            datatype=ua.NodeId(ua.ObjectIds.Range),
        )

    async def _run_state(self, parent: Node, drive: str) -> Node:
        """A MultiStateDiscreteType variable: a SCADA shows its EnumStrings' word."""
        text = f"{drive}.{RUN_STATE}"
        variable = await self._variable(parent, text, RUN_STATE, ua.VariantType.UInt32)
        base = ua.NodeId(ua.ObjectIds.BaseDataVariableType)
        await variable.delete_reference(base, ua.ObjectIds.HasTypeDefinition)
        discrete = ua.NodeId(ua.ObjectIds.MultiStateDiscreteType)
        await variable.add_reference(discrete, ua.ObjectIds.HasTypeDefinition)
        words = [ua.LocalizedText(word) for word in RUN_STATES]
        await variable.add_property(
            self.node_id(f"{text}.EnumStrings"),
            ua.QualifiedName("EnumStrings", 0),
            ua.Variant(words, ua.VariantType.LocalizedText),
            datatype=ua.NodeId(ua.ObjectIds.LocalizedText),
        )
        return variable

    async def _method(self, parent: Node, drive: str, command: str, call: MethodCall) -> None:
        name = method_name(command)
        answer = ua.Argument(
            Name="Answer",
            DataType=ua.NodeId(ua.ObjectIds.String),
            ValueRank=-1,
            Description=ua.LocalizedText('"ok", or why not'),
        )
        inputs = [FREQUENCY_ARGUMENT] if command in TAKES_FREQUENCY else []
        await parent.add_method(
            self.node_id(f"{drive}.{name}"), self.name(name), call, inputs, [answer]
        )


def _zero(kind: ua.VariantType) -> object:
    if kind is ua.VariantType.String:
        return ""
    if kind is ua.VariantType.Boolean:
        return False
    if kind in (ua.VariantType.Float, ua.VariantType.Double):
        return 0.0
    return 0


def bus_order(drives: Sequence[DriveSettings]) -> dict[str, list[DriveSettings]]:
    """The drives by bus, in the configuration's order."""
    buses: dict[str, list[DriveSettings]] = {}
    for drive in drives:
        buses.setdefault(drive.bus, []).append(drive)
    return buses
