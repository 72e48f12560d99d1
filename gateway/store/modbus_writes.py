"""SCADA's writes as events: counted per client, unit id and minute, one `modbus_writes` each.

A SCADA writing a set-point every second would otherwise put 86400 events a day into the store
and onto the broker; who wrote to which drive, how often, and whether the drive took it is what an
audit needs. A minute's tally goes out once the minute is over (and at stop). Until then it is
kept in the store as it grows (`EventStore.keep_tally`, written within the second), so a gateway
killed in the middle of a minute loses none of it: the next start records what it had counted.

    {"client": "10.0.0.5", "unit_id": 1, "drive": "pump1", "from": "...", "to": "...",
     "writes": 60, "refused": 0, "functions": ["06"], "registers": ["2001H"]}

`registers` lists the first register of each write, at most `MAX_REGISTERS` different ones.
"""

from __future__ import annotations

import asyncio
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Final

from gateway.modbus.functions import lookup
from gateway.poller.drive_state import iso_time
from gateway.profile import format_register
from gateway.store.events import EventStore
from gateway.store.records import EventType, Json
from gateway.tasks import ServiceTasks, cancel_and_wait

MINUTE_S: Final = 60.0
CHECK_EVERY_S: Final = 5.0
MAX_REGISTERS: Final = 16


@dataclass(slots=True)
class _Tally:
    first: float
    last: float
    writes: int = 0
    refused: int = 0
    functions: set[int] = field(default_factory=set)
    registers: list[int] = field(default_factory=list)


class WriteTally:
    def __init__(
        self, events: EventStore, drive_of: Callable[[int], str | None], tasks: ServiceTasks
    ) -> None:
        self.events = events
        self.drive_of = drive_of
        """Unit id → the drive's name (None: no such drive), as routed now."""
        self.tasks = tasks
        self._tallies: dict[tuple[str, int, int], _Tally] = {}
        self._task: asyncio.Task[None] | None = None

    def count(self, client: str, unit_id: int, pdu: bytes, refused: bool) -> None:
        """One request from `client`; `refused`: answered with an exception (the drive's or the
        gateway's)."""
        if not pdu or not lookup(pdu[0]).writes:
            return
        now = time.time()
        key = (client_host(client), unit_id, int(now // MINUTE_S))
        tally = self._tallies.get(key)
        if tally is None:
            tally = self._tallies[key] = _Tally(now, now)
        tally.last = now
        tally.writes += 1
        tally.functions.add(pdu[0])
        if refused:
            tally.refused += 1
        if len(pdu) >= 3:
            (register,) = struct.unpack(">H", pdu[1:3])
            if register not in tally.registers and len(tally.registers) < MAX_REGISTERS:
                tally.registers.append(register)
        self.events.keep_tally(
            _tally_key(key),
            EventType.MODBUS_WRITES,
            self._data(key[0], unit_id, tally),
            drive=self.drive_of(unit_id),
            at=tally.first,
        )

    async def start(self) -> None:
        self._task = self.tasks.start("store:modbus-writes", self._run())

    async def stop(self) -> None:
        if self._task is not None:
            await cancel_and_wait(self._task, 0.2)
            self._task = None
        self.flush(until_minute=None)

    def flush(self, until_minute: int | None) -> None:
        """Record the tallies of every minute before `until_minute` (None: all of them)."""
        for key in sorted(self._tallies, key=lambda k: self._tallies[k].first):
            client, unit_id, minute = key
            if until_minute is not None and minute >= until_minute:
                continue
            tally = self._tallies.pop(key)
            self.events.record(
                EventType.MODBUS_WRITES,
                self._data(client, unit_id, tally),
                drive=self.drive_of(unit_id),
                at=tally.first,
                settles=_tally_key(key),
            )

    async def _run(self) -> None:
        while True:
            await asyncio.sleep(CHECK_EVERY_S)
            self.flush(until_minute=int(time.time() // MINUTE_S))

    def _data(self, client: str, unit_id: int, tally: _Tally) -> Json:
        return {
            "client": client,
            "unit_id": unit_id,
            "drive": self.drive_of(unit_id),
            "from": iso_time(tally.first),
            "to": iso_time(tally.last),
            "writes": tally.writes,
            "refused": tally.refused,
            "functions": [f"{code:02X}" for code in sorted(tally.functions)],
            "registers": [format_register(register) for register in tally.registers],
        }


def _tally_key(key: tuple[str, int, int]) -> str:
    client, unit_id, minute = key
    return f"modbus_writes {client} {unit_id} {minute}"


def client_host(client: str) -> str:
    """ "tcp:10.0.0.5:51234" → "10.0.0.5" (the port changes with each connection)."""
    address = client.removeprefix("tcp:")
    host, _, port = address.rpartition(":")
    return host if host and port.isdigit() else address
