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
    <drive>.<Method>                 RunForward, Stop... (CamelCase of the profile's commands)

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
from gateway.opcua.values import ANY, engineering_units, status_value, variant_type
from gateway.settings import DriveSettings
from gateway.sparkplug.metrics import unit_of

NAMESPACE: Final = "urn:invt-gateway:drives"
NOT_SERVED: Final = frozenset({"last_seen"})
"""The SourceTimestamp says when."""
SETPOINT: Final = "set_frequency_hz"
"""The set frequency as read back; written, it is the `frequency_hz` of a `/set`."""

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
            nodes.variables[key] = (variable.nodeid, kind)
            await self.server.write_attribute_value(variable.nodeid, waiting)
            takes_setpoint = key == SETPOINT and bool(profile.commands)
            if self.commands_enabled and (key in writable or takes_setpoint):
                await variable.set_writable()
                self.targets[variable.nodeid] = WriteTarget(command_drive, key, key in writable)
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

    async def _method(self, parent: Node, drive: str, command: str, call: MethodCall) -> None:
        name = method_name(command)
        answer = ua.Argument(
            Name="Answer",
            DataType=ua.NodeId(ua.ObjectIds.String),
            ValueRank=-1,
            Description=ua.LocalizedText('"ok", or why not'),
        )
        await parent.add_method(
            self.node_id(f"{drive}.{name}"), self.name(name), call, [], [answer]
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
