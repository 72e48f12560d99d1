"""What the console asks of a drive: reads for the parameter browser and the fault history, and
the operator's commands and writes.

Every request takes the path a Modbus-TCP request takes after its frame is parsed: the same
`modbus_tcp.read_only` and `modbus_tcp.access` rules (the console user's role standing for a TLS
client's role: the same names), then the router, which applies the drive's `ram_writes`, word
limit and queue. A policy refusal is told as such (HTTP 403) rather than as a drive's exception.
Each write is recorded as an audit event: who, what, when, and what came of it.
"""

from __future__ import annotations

import asyncio
import struct
from collections.abc import Awaitable, Callable, Mapping
from dataclasses import dataclass
from typing import Any, Final

from gateway.console.auth import Identity
from gateway.console.decode import describe
from gateway.console.events import Category, EventStore, GatewayEvent
from gateway.errors import ModbusError, OperationError
from gateway.modbus.functions import (
    READ_HOLDING_REGISTERS,
    WRITE_SINGLE_REGISTER,
    changes_nothing,
    is_exception,
)
from gateway.poller import Poller
from gateway.profile import (
    COMMUNICATION_REGISTERS,
    Point,
    RegisterWrite,
    parse_parameter,
    resolve,
)
from gateway.profile.parameter_tables import CHANGE_MARKS
from gateway.profile.parameters import FAULT_HISTORY, Parameter, parameter_groups
from gateway.profile.points import for_series
from gateway.profile.ram_writes import ram_write_address
from gateway.routing import Router
from gateway.setpoint_limit import setpoint_refusal
from gateway.settings import DriveSettings
from gateway.tcp.access import AccessPolicy

MAX_BLOCK: Final = 16
"""INVT drives answer at most 16 words per read."""
REGISTER_BLOCKS: Final = ("2000H", "2100H", "3000H")
MAX_FOUND: Final = 60
"""Rows a search answers at most: more say the words were too few."""


@dataclass(frozen=True, slots=True)
class Policy:
    """Modbus-TCP's write policy, as the console must obey it too."""

    read_only: bool
    access: AccessPolicy | None
    commands_enabled: bool

    def refusal(self, unit_id: int, pdu: bytes, role: str) -> str | None:
        if not changes_nothing(pdu):
            if not self.commands_enabled:
                return "console.commands_enabled is false: the console only shows"
            if self.read_only:
                return "modbus_tcp.read_only is true: every write is refused"
        if self.access is not None:
            refusal = self.access.check(unit_id, pdu, role)
            if refusal is not None:
                rule = self.access.rules[refusal.rule].label
                return f"refused by modbus_tcp.access rule {rule}"
        return None


Explain = Callable[[int], Awaitable[str]]
"""What a drive's exception code to a write means, said for that write (without one: the
words of the drive's profile)."""


class DriveOperations:
    def __init__(
        self,
        drives: Mapping[str, DriveSettings],
        router: Router,
        policy: Policy,
        poller: Poller | None,
        events: EventStore,
    ) -> None:
        self.drives = drives
        self.router = router
        self.policy = policy
        self.poller = poller
        self.events = events

    # -- reads ------------------------------------------------------------------------------

    async def parameter_group(self, who: Identity, drive: str, group: str) -> list[dict[str, Any]]:
        """The group's registers with names, units and scaled values from the profile: for a
        parameter group, the drive's series table, with the manual's words for each value."""
        if group not in REGISTER_BLOCKS:
            return await self._parameter_rows(who, drive, _series_group(self._drive(drive), group))
        points = _group_points(group)
        values = await self._read_points(who, drive, [p.address for p in points])
        profile = self._drive(drive).profile
        return [
            {
                "name": p.label,
                "address": f"{p.address:04X}H",
                "description": p.description,
                "unit": p.unit,
                "decimals": p.decimals,
                "raw": values.get(p.address),
                "value": (
                    None if values.get(p.address) is None else p.show(values[p.address], profile)
                ),
                "writable": _writable(self._drive(drive), p),
            }
            for p in points
        ]

    async def _parameter_rows(
        self, who: Identity, drive: str, rows: tuple[Parameter, ...]
    ) -> list[dict[str, Any]]:
        values = await self._read_points(who, drive, [row.address for row in rows])
        profile = self._drive(drive).profile

        def shown(row: Parameter, raw: int) -> str:
            # The fault history's codes in the drive's own fault table, as everywhere else.
            if row.name in FAULT_HISTORY:
                return f"{raw} ({profile.faults.describe(raw)})"
            return row.show(raw)

        def differs(row: Parameter) -> bool | None:
            raw = values.get(row.address)
            return None if raw is None or not row.default_known else raw != row.default

        return [
            {
                "name": row.name,
                "group": row.group,
                "address": f"{row.address:04X}H",
                "description": row.description,
                "unit": row.unit,
                "decimals": row.decimals,
                "raw": values.get(row.address),
                "value": None if row.address not in values else shown(row, values[row.address]),
                "writable": not row.read_only,
                "change": CHANGE_MARKS[_mark(row)],
                "range": row.range_text(),
                "default": row.shown_default(),
                "differs_from_default": differs(row),
                "choices": [{"value": value, "words": text} for value, text in row.choices],
                "hint": row.hint,
                "confirmed": row.confirmed,
                "source": row.source,
            }
            for row in rows
        ]

    def parameter_groups(self, drive: str) -> tuple[str, ...]:
        """The groups of the drive's series table: the browser's tabs."""
        return self._drive(drive).profile.parameter_table.groups

    async def find_parameters(self, who: Identity, drive: str, text: str) -> list[dict[str, Any]]:
        """The drive's parameters `text` names (P00.03, 0003H, or words of the name), read."""
        found = self._drive(drive).profile.parameter_table.find(text)
        return await self._parameter_rows(who, drive, found[:MAX_FOUND])

    async def fault_history(self, who: Identity, drive: str) -> list[dict[str, Any]]:
        """P07.27 (the current fault) … P07.32, decoded with the drive's own fault table."""
        settings = self._drive(drive)
        start = parse_parameter(FAULT_HISTORY[0])
        codes = await self._read(who, settings, start, len(FAULT_HISTORY))
        faults = [settings.profile.fault_fields(code) for code in codes]
        return [
            {
                "parameter": name,
                "code": fault["fault_code"],
                "name": fault["fault_name"],
                "description": fault["fault_description"],
            }
            for name, fault in zip(FAULT_HISTORY, faults, strict=True)
        ]

    # -- writes -----------------------------------------------------------------------------

    async def command(self, who: Identity, drive: str, command: str) -> dict[str, Any]:
        profile = self._drive(drive).profile
        if command not in profile.commands:
            known = ", ".join(profile.commands) or "none"
            raise OperationError(400, f"unknown command {command!r}: one of {known}")
        try:
            writes = profile.control_writes(command, None)
        except ValueError as exc:
            raise OperationError(400, str(exc)) from None
        return await self._write_steps(who, drive, writes)

    async def set_frequency(self, who: Identity, drive: str, hz: float) -> dict[str, Any]:
        profile = self._drive(drive).profile
        try:
            writes = profile.control_writes(None, profile.setpoint_word(hz))
        except ValueError as exc:
            raise OperationError(400, str(exc)) from None
        settings = self._drive(drive)
        read_at_start = self.poller.max_frequency_hz if self.poller is not None else {}

        async def explain(code: int) -> str:
            return await setpoint_refusal(self.router, settings, hz, code, read_at_start)

        return await self._write_steps(who, drive, writes, explain)

    async def write_parameter(
        self, who: Identity, drive: str, name: str, value: str, ram: bool
    ) -> dict[str, Any]:
        try:
            point = for_series(resolve(name), self._drive(drive).profile)
            raw = point.encode(value)
        except ValueError as exc:
            raise OperationError(400, str(exc)) from None
        if not _writable(self._drive(drive), point):
            raise OperationError(400, f"{point.label} is read-only")
        address = point.address
        if ram:
            settings = self._drive(drive)
            if not settings.profile.ram_writes_supported:
                raise OperationError(400, f"{settings.model} has no RAM-only parameter writes")
            address = ram_write_address(address)

        exceptions = self._drive(drive).profile.exceptions

        async def explain(code: int) -> str:
            note = point.borrowed_note
            words = exceptions.describe(code)
            return f"{words}; {note}" if note else words

        return await self._write(who, drive, address, raw, Category.CONFIGURATION, explain)

    # -- the path every request takes --------------------------------------------------------

    async def _write_steps(
        self,
        who: Identity,
        drive: str,
        writes: tuple[RegisterWrite, ...],
        explain: Explain | None = None,
    ) -> dict[str, Any]:
        """The profile's writes for a command, in order, one word at a time (the console writes
        with 06H only), with the pauses its state machine asks for."""
        done: list[str] = []
        for step in writes:
            for offset, word in enumerate(step.words):
                address = step.start + offset
                answer = await self._write(who, drive, address, word, Category.CONTROL, explain)
                done.append(answer["write"])
            if step.pause_s:
                await asyncio.sleep(step.pause_s)
        return {"ok": True, "write": "; ".join(done)}

    async def _write(
        self,
        who: Identity,
        drive: str,
        address: int,
        raw: int,
        category: Category,
        explain: Explain | None = None,
    ) -> dict[str, Any]:
        settings = self._drive(drive)
        if not settings.profile.commands:
            raise OperationError(
                400, f"{drive} is a {settings.profile.display_name}: no drive commands"
            )
        pdu = struct.pack(">BHH", WRITE_SINGLE_REGISTER, address, raw)
        what = describe(pdu, None, settings.profile).removeprefix("write ")
        try:
            reply = await self._send(who, settings, pdu)
        except OperationError as exc:
            self._audit(who, drive, settings, category, what, f"refused: {exc}")
            raise
        if is_exception(reply):
            code = reply[1]
            exceptions = settings.profile.exceptions
            words = exceptions.describe(code) if explain is None else await explain(code)
            result = f"drive refused: {words}"
            self._audit(who, drive, settings, category, what, result)
            raise OperationError(502, result)
        self._audit(who, drive, settings, category, what, "ok")
        if self.poller is not None:
            self.poller.poll_now(drive)  # its new state shows at once
        return {"ok": True, "write": what}

    async def _read_points(self, who: Identity, drive: str, addresses: list[int]) -> dict[int, int]:
        settings = self._drive(drive)
        values: dict[int, int] = {}
        for start, count in _blocks(addresses):
            try:
                words = await self._read(who, settings, start, count)
            except OperationError as exc:
                if exc.status != 502:
                    raise
                continue  # the drive refused this block (not on this model): the rest may answer
            values.update({start + i: word for i, word in enumerate(words)})
        return values

    async def _read(
        self, who: Identity, settings: DriveSettings, start: int, count: int
    ) -> list[int]:
        pdu = struct.pack(">BHH", READ_HOLDING_REGISTERS, start, count)
        reply = await self._send(who, settings, pdu)
        if is_exception(reply):
            words = settings.profile.exceptions.describe(reply[1])
            raise OperationError(502, f"drive refused: {words}")
        return list(struct.unpack(f">{count}H", reply[2 : 2 + 2 * count]))

    async def _send(self, who: Identity, settings: DriveSettings, pdu: bytes) -> bytes:
        unit_id = settings.unit_id
        refusal = self.policy.refusal(unit_id, pdu, str(who.role))
        if refusal is not None:
            raise OperationError(403, refusal)
        try:
            reply = await self.router.execute(unit_id, pdu, client=who.client)
            assert reply is None or isinstance(reply, bytes)
        except ModbusError as exc:
            words = settings.profile.exceptions.describe(exc.code)
            raise OperationError(502, f"{words} ({exc})") from None
        assert reply is not None  # only broadcasts have none
        return reply

    def _drive(self, name: str) -> DriveSettings:
        settings = self.drives.get(name)
        if settings is None:
            raise OperationError(404, f"no drive named {name!r}")
        return settings

    def _audit(
        self,
        who: Identity,
        drive: str,
        settings: DriveSettings,
        category: Category,
        what: str,
        result: str,
    ) -> None:
        event = GatewayEvent(
            "write",
            what,
            drive,
            settings.bus,
            who=who.client,
            result=result,
            address=who.address,
            category=category,
        )
        self.events.record(event)


def _group_points(group: str) -> list[Point]:
    high = int(group[:2], 16)
    return [
        resolve(r.name) for r in COMMUNICATION_REGISTERS if r.address >> 8 == high and r.readable
    ]


def _series_group(settings: DriveSettings, group: str) -> tuple[Parameter, ...]:
    groups = parameter_groups(settings.profile.parameters)
    if group not in groups:
        known = ", ".join((*groups, *REGISTER_BLOCKS))
        raise OperationError(404, f"no group {group!r}: one of {known}")
    return groups[group]


def _mark(row: Parameter) -> str:
    """The manual's change mark of a row: ● read-only, ◎ stopped only, ○ any time."""
    if row.read_only:
        return "●"
    return "◎" if row.locked_while_running else "○"


def _writable(settings: DriveSettings, point: Point) -> bool:
    if point.label.startswith("P"):
        row = settings.profile.parameter_table.at(point.address & 0x7FFF)
        return row is not None and not row.read_only
    register = next((r for r in COMMUNICATION_REGISTERS if r.address == point.address), None)
    return register is not None and register.writable


def _blocks(addresses: list[int]) -> list[tuple[int, int]]:
    """Contiguous runs of at most MAX_BLOCK words: as few transactions as the drive allows."""
    blocks: list[tuple[int, int]] = []
    for address in sorted(set(addresses)):
        if blocks and address == blocks[-1][0] + blocks[-1][1] and blocks[-1][1] < MAX_BLOCK:
            blocks[-1] = (blocks[-1][0], blocks[-1][1] + 1)
        else:
            blocks.append((address, 1))
    return blocks
