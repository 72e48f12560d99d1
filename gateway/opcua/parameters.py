"""A drive's parameters as nodes: `Parameters/P00.03`..., one per row of its series' parameter
table (`DriveProfile.parameters`, the table the console, MQTT and `invt-gateway params` read).

    <drive>.Parameters                  the folder
    <drive>.Parameters.P00.03           the parameter (browse name P00.03, its manual's name as
                                        its description); Double when the table scales it,
                                        Int16 when its range is signed, else UInt16
    <drive>.Parameters.P00.03.EngineeringUnits, .EURange    from the table's row

A parameter is not polled: a client's Read of one reads it once through the bus, as MQTT's
`read_parameter` does (`parse_read` and `Commands.read`: the same register, scale and sign, at
a client's priority, never the poller's), and keeps what it read for `parameter_max_age_s`; a
Read within that time is answered from the node. A drive's refusal or silence is kept the same
time, as the value's StatusCode (the line is not asked again and again for a parameter it
refuses). At most `READS_PER_REQUEST` parameters are read from the line for one Read request;
the others answer what they held.

A write goes through the command path as MQTT's `{"parameter": "P00.11", "value": 10.0}` does
(`command_path.WriteTarget`): the table's range and step, the role, `commands_enabled`; the
parameter is read again at the next Read.
"""

from __future__ import annotations

import asyncio
import datetime
import logging
import time
from dataclasses import dataclass
from typing import Any, Final

from asyncua import Node, ua

from gateway.errors import CommandRefused, ModbusError
from gateway.mqtt.commands import CommandDrive, Commands, modbus_error
from gateway.mqtt.requests import parse_read
from gateway.opcua.command_path import WriteTarget, status_of
from gateway.opcua.values import engineering_units, status_value
from gateway.profile.parameters import Parameter

log = logging.getLogger(__name__)

FOLDER: Final = "Parameters"
READS_PER_REQUEST: Final = 32
"""A Read of a whole folder (a browser showing 425 values) reads the first ones from the line,
not all: it would hold the request for seconds, and the line for the poller's time."""

YIELD_EVERY: Final = 20
"""Nodes made between two turns of the event loop: making one takes ~1 ms on a small box."""


def parameter_type(row: Parameter) -> ua.VariantType:
    if row.decimals:
        return ua.VariantType.Double
    return ua.VariantType.Int16 if row.signed else ua.VariantType.UInt16


@dataclass(slots=True)
class ParameterNode:
    drive: CommandDrive
    row: Parameter
    kind: ua.VariantType
    read_at: float | None = None
    """Monotonic time of the last read from the line (its value or its refusal)."""


class ParameterNodes:
    """Every drive's parameter nodes, and their reads through the bus on a client's Read."""

    def __init__(
        self, commands: Commands, max_age_s: float, shown: str | tuple[str, ...] = "all"
    ) -> None:
        self.commands = commands
        self.max_age_s = max_age_s
        self.shown = shown
        """`opcua.parameters`: `all`, `none`, or groups (P00) and codes (P00.03)."""
        self.nodes: dict[ua.NodeId, ParameterNode] = {}
        self._locks: dict[ua.NodeId, asyncio.Lock] = {}
        self.server: Any = None

    async def add(
        self, ns: int, drive_node: Node, drive: CommandDrive, writable: bool
    ) -> dict[ua.NodeId, WriteTarget]:
        """The drive's folder and its parameters; the writable ones' targets."""
        rows = [row for row in drive.profile.parameters if self._shown(row)]
        targets: dict[ua.NodeId, WriteTarget] = {}
        if not rows:
            return targets
        name = drive.name
        folder = await drive_node.add_folder(
            ua.NodeId(f"{name}.{FOLDER}", ns), ua.QualifiedName(FOLDER, ns)
        )
        now = datetime.datetime.now(datetime.UTC)
        waiting = status_value(ua.StatusCodes.BadWaitingForInitialData, now)
        for number, row in enumerate(rows):
            if number % YIELD_EVERY == 0:
                await asyncio.sleep(0)  # the other doors served while a drive's 400 are made
            text = f"{name}.{FOLDER}.{row.name}"
            kind = parameter_type(row)
            variable = await folder.add_variable(
                ua.NodeId(text, ns), ua.QualifiedName(row.name, ns), ua.Variant(0, kind), kind
            )
            await variable.write_attribute(
                ua.AttributeIds.Description,
                ua.DataValue(ua.Variant(ua.LocalizedText(row.description))),
            )
            await _properties(variable, text, ns, row)
            await variable.write_value(waiting)
            self.nodes[variable.nodeid] = ParameterNode(drive, row, kind)
            if writable and not row.read_only:
                await variable.set_writable()
                targets[variable.nodeid] = WriteTarget(drive, row.name, "parameter")
        return targets

    def _shown(self, row: Parameter) -> bool:
        if isinstance(self.shown, str):
            return self.shown == "all"
        return row.name in self.shown or row.group in self.shown

    def written(self, node_id: ua.NodeId) -> None:
        """A write went to the drive: the next Read asks the drive again."""
        if node_id in self.nodes:
            self.nodes[node_id].read_at = None

    async def before_read(self, event: Any, dispatcher: Any) -> None:
        """asyncua's PreRead callback: the stale parameters of the request read from the line,
        before the request reads the nodes."""
        params = event.request_params
        now = time.monotonic()
        stale = []
        for item in params.NodesToRead:
            node = self.nodes.get(item.NodeId)
            if node is None or item.AttributeId != ua.AttributeIds.Value:
                continue
            if node.read_at is None or now - node.read_at > self.max_age_s:
                stale.append(item.NodeId)
        if stale:
            await asyncio.gather(*(self._refresh(n) for n in stale[:READS_PER_REQUEST]))

    async def _refresh(self, node_id: ua.NodeId) -> None:
        lock = self._locks.setdefault(node_id, asyncio.Lock())
        async with lock:  # two clients asking at once: one read
            node = self.nodes[node_id]
            if node.read_at is not None and time.monotonic() - node.read_at <= self.max_age_s:
                return
            value = await self._read(node)
            node.read_at = time.monotonic()
            await self.server.write_attribute_value(node_id, value)

    async def _read(self, node: ParameterNode) -> ua.DataValue:
        drive = node.drive
        now = datetime.datetime.now(datetime.UTC)
        try:
            read = parse_read({"parameter": node.row.name}, drive.read_limit, drive.profile)
            words = await self.commands.read(drive, read)
        except (ModbusError, CommandRefused) as exc:
            log.info("OPC UA: %s %s not read: %s", drive.name, node.row.name, exc)
            return status_value(_status(exc), now)
        value = read.result(words)["value"]
        try:
            variant = ua.Variant(value if node.kind is ua.VariantType.Double else int(value))
            variant = ua.Variant(variant.Value, node.kind)
        except (TypeError, ValueError):
            return status_value(ua.StatusCodes.BadTypeMismatch, now)
        return ua.DataValue(variant, SourceTimestamp=now, ServerTimestamp=now)


def _status(exc: ModbusError | CommandRefused) -> int:
    if isinstance(exc, CommandRefused):
        return status_of({"error": exc.reason})
    word, code = modbus_error(exc)
    return status_of({"error": word, "exception_code": code})


async def _properties(variable: Node, text: str, ns: int, row: Parameter) -> None:
    units = engineering_units(row.unit)
    if units is not None:
        await variable.add_property(
            ua.NodeId(f"{text}.EngineeringUnits", ns),
            ua.QualifiedName("EngineeringUnits", 0),
            ua.Variant(units, ua.VariantType.ExtensionObject),
            datatype=ua.NodeId(ua.ObjectIds.EUInformation),
        )
    if not row.hexadecimal:
        scale = 10**row.decimals
        low, high = row.minimum / scale, row.maximum / scale
        await variable.add_property(
            ua.NodeId(f"{text}.EURange", ns),
            ua.QualifiedName("EURange", 0),
            ua.Variant(ua.Range(Low=low, High=high), ua.VariantType.ExtensionObject),
            datatype=ua.NodeId(ua.ObjectIds.Range),
        )
