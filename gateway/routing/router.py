"""Routing: a Modbus unit id (or a drive's name) to a drive, its bus and its address on that bus.

The router is the one way to a drive, for every part that asks: the TCP server (`execute`, by
unit id, or `submit` for a read that is one transaction), the MQTT commands (`request`, by the
`Route` they resolved once) and the poller (`poll`). It owns the poll cache, and is the only
part that touches it:

    read-through   a 03H read of a drive with `cache_max_age_s` is answered from the cache when
                   every word asked for is fresh enough; otherwise it goes to the drive
    write-through  a write invalidates the drive's cache before it goes out and again when it is
                   answered: no poll issued before or during the write is ever stored
    polls          `poll` always asks the drive (a poll is how the cache learns) and stores what
                   it says, unless a write went out since the poll was issued
    offline        a drive its bus isolates as offline is forgotten (`on_drive_health`)

Besides, the router applies what a drive's profile says about its requests (handed in as data:
the router knows no vendor): reads and writes over the drive's word limit are split into several
transactions and reassembled; writes to parameters may go to their RAM-only address.
"""

from __future__ import annotations

import asyncio
import struct
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass

from gateway.bus import Bus, Priority
from gateway.bus.queue import Waiter
from gateway.errors import GatewayPathUnavailable
from gateway.modbus.functions import (
    MAX_READ_REGISTERS,
    READ_HOLDING_REGISTERS,
    WRITE_MULTIPLE_REGISTERS,
    WRITE_SINGLE_REGISTER,
    is_exception,
    join_replies,
    known_function,
    lookup,
    needs_split,
    split_request,
)
from gateway.modbus.rtu import BROADCAST_ADDRESS
from gateway.routing.cache import RegisterCache

_READ = Priority.READ
"""Read per taskless read: a module global, not the enum's attribute (`gateway.bus.queue`
says why)."""

MAX_READ_WORDS = MAX_READ_REGISTERS  # the Modbus limit; beyond it the request is the drive's
POLL_CLIENT = "poll"
"""The bus's name for the poller's requests (its own round-robin share, like one SCADA client)."""


@dataclass(frozen=True, slots=True)
class Route:
    unit_id: int
    drive: str
    bus: Bus
    address: int
    timeout_s: float | None = None
    retries: int | None = None
    max_words: int | None = None
    """Split 03H/04H/10H requests into transactions of at most this many words."""
    ram_address: Callable[[int], int] | None = None
    """Maps a written register to its RAM-only twin (or itself) for 06H/10H writes."""
    cache_max_age_s: float | None = None
    """Answer 03H reads from the poll cache when every value is at most this old."""


class Router:
    def __init__(self, routes: Iterable[Route], buses: Iterable[Bus]) -> None:
        self.cache = RegisterCache()
        self._routes = {route.unit_id: route for route in routes}
        self._by_drive = {route.drive: route for route in self._routes.values()}
        self._by_bus_address = {(r.bus.name, r.address): r for r in self._routes.values()}
        self.buses = tuple(buses)

    def replace_routes(self, routes: Iterable[Route], buses: Iterable[Bus]) -> None:
        """A reload: the next request sees the new table (a removed drive's unit id answers 0AH,
        an added one answers at once, one on a reopened bus goes to the new bus) and broadcasts
        the new buses; requests on their way keep the route they resolved."""
        before = set(self._by_drive)
        self.buses = tuple(buses)
        self._routes = {route.unit_id: route for route in routes}
        self._by_drive = {route.drive: route for route in self._routes.values()}
        self._by_bus_address = {(r.bus.name, r.address): r for r in self._routes.values()}
        for gone in before - set(self._by_drive):
            self.cache.forget(gone)

    @property
    def routes(self) -> list[Route]:
        return sorted(self._routes.values(), key=lambda r: r.unit_id)

    def route(self, unit_id: int) -> Route:
        route = self._routes.get(unit_id)
        if route is None:
            raise GatewayPathUnavailable(f"no drive has unit id {unit_id}")
        return route

    def route_for_drive(self, name: str) -> Route:
        route = self._by_drive.get(name)
        if route is None:
            raise GatewayPathUnavailable(f"no drive named {name!r}")
        return route

    # -- the route API -------------------------------------------------------------------------

    async def execute(
        self, unit_id: int, pdu: bytes, *, client: str, priority: Priority | None = None
    ) -> bytes | None:
        """Carry `pdu` to the drive with `unit_id`; its reply PDU, or None for a broadcast."""
        if unit_id == BROADCAST_ADDRESS:
            for route in self._routes.values():  # every drive may have changed
                self.cache.invalidate(route.drive)
            await self._broadcast(pdu, client)
            return None
        return await self.request(self.route(unit_id), pdu, client=client, priority=priority)

    async def request(
        self, route: Route, pdu: bytes, *, client: str, priority: Priority | None = None
    ) -> bytes:
        """Carry `pdu` to the drive of `route`: from the cache when it may, through it always."""
        if lookup(pdu[0]).writes:
            return await self._write_through(route, pdu, client, priority or Priority.WRITE)
        if route.cache_max_age_s is not None:
            cached = self._from_cache(route, pdu)
            if cached is not None:
                return cached
        return await self._forward(route, pdu, client, priority or Priority.READ)

    def submit(self, unit_id: int, pdu: bytes, client: str, waiter: Waiter) -> bool:
        """`execute` without a task, for a read that is one bus transaction: the reply (from
        the cache, or the drive's) goes to `waiter`. False when the request needs `execute`
        (a write, a broadcast, a read the drive's word limit splits); a refusal before the bus
        (no such unit id, drive offline, queue full) is raised. `pdu` has passed the front
        door's `check_request` (the Modbus-TCP server's reads: one registry lookup, one route
        lookup, then the bus, as `_send` goes to it)."""
        function = known_function(pdu[0]) or lookup(pdu[0])
        if unit_id == BROADCAST_ADDRESS or function.writes:
            return False
        route = self._routes.get(unit_id)
        if route is None:
            route = self.route(unit_id)  # raises, saying which unit id
        max_words = route.max_words
        if (
            max_words is not None
            and len(pdu) >= 5
            and (pdu[3] << 8 | pdu[4]) > max_words  # a split read asks for more words
            and needs_split(pdu, max_words)
        ):
            # The first tests never change the verdict (only 03H/04H/10H requests split, each
            # five bytes or more with its quantity in bytes 3-4, and only beyond `max_words`):
            # they spare the reads that fit, nearly all, the remembered verdict's lookup.
            return False
        if route.cache_max_age_s is not None:
            cached = self._from_cache(route, pdu)
            if cached is not None:
                waiter.set_result(cached)
                return True
        # A read is never rewritten to a RAM address (`_to_ram` takes 06H/10H only).
        bus, address, timeout_s, retries = route.bus, route.address, route.timeout_s, route.retries
        bus.submit(address, pdu, waiter, _READ, client, timeout_s, retries, function.coalescable)
        return True

    async def poll(
        self, route: Route, start: int, count: int, function: int = READ_HOLDING_REGISTERS
    ) -> bytes:
        """Read `count` words (or bits) from `start` of the drive with `function` (01H-04H),
        never from the cache, at poll priority; the reply PDU (an exception reply too). What
        the drive says of its holding registers goes into the cache (the one table it serves)."""
        pdu = struct.pack(">BHH", function, start, count)
        # The cache only takes what was true when the poll was issued and no write followed.
        issued_at = time.monotonic()
        generation = self.cache.generation(route.drive)
        reply = await self._forward(route, pdu, POLL_CLIENT, Priority.POLL)
        if function == READ_HOLDING_REGISTERS and not is_exception(reply):
            words = struct.unpack(f">{(len(reply) - 2) // 2}H", reply[2:])
            self.cache.store(route.drive, start, words, issued_at, generation)
        return reply

    def on_drive_health(self, bus: str, address: int, online: bool) -> None:
        """Bus listener: nothing an offline drive said before may be served as current."""
        route = self._by_bus_address.get((bus, address))
        if route is not None and not online:
            self.cache.forget(route.drive)

    # -- inside ----------------------------------------------------------------------------------

    async def _write_through(
        self, route: Route, pdu: bytes, client: str, priority: Priority
    ) -> bytes:
        # Whatever the cache holds for this drive may be what the write is about to change; a
        # poll issued while the write is on its way may read it half done: forget both.
        self.cache.invalidate(route.drive)
        try:
            return await self._forward(route, pdu, client, priority)
        finally:
            self.cache.invalidate(route.drive)

    async def _forward(self, route: Route, pdu: bytes, client: str, priority: Priority) -> bytes:
        sent = pdu if route.ram_address is None else _to_ram(pdu, route.ram_address)
        split = None if route.max_words is None else split_request(sent, route.max_words)
        if split is not None:
            reply = await self._execute_split(route, sent, split, client, priority)
        else:
            reply = await self._send(route, sent, client, priority)
        if sent is not pdu and not is_exception(reply):
            # The drive echoes the RAM address; the client asked for, and expects, its own.
            reply = reply[:1] + pdu[1:3] + reply[3:]
        return reply

    def _from_cache(self, route: Route, pdu: bytes) -> bytes | None:
        if pdu[0] != READ_HOLDING_REGISTERS or len(pdu) != 5:
            return None
        start, count = struct.unpack(">HH", pdu[1:5])
        assert route.cache_max_age_s is not None
        values = self.cache.lookup(route.drive, start, count, route.cache_max_age_s)
        if values is None:
            return None
        return struct.pack(f">BB{count}H", pdu[0], 2 * count, *values)

    async def _send(self, route: Route, pdu: bytes, client: str, priority: Priority) -> bytes:
        reply: asyncio.Future[bytes | None] = asyncio.get_running_loop().create_future()
        bus, address, timeout_s, retries = route.bus, route.address, route.timeout_s, route.retries
        bus.submit(address, pdu, reply, priority, client, timeout_s, retries)
        answer = await reply
        assert answer is not None  # only broadcasts have no reply
        return answer

    async def _broadcast(self, pdu: bytes, client: str) -> None:
        if not lookup(pdu[0]).broadcastable:
            raise GatewayPathUnavailable(
                f"unit id 0 is broadcast: only write function codes, not {pdu[0]:#04x}"
            )
        # Every line gets it: a broadcast means every drive the gateway reaches.
        await asyncio.gather(
            *(
                bus.request(BROADCAST_ADDRESS, pdu, priority=Priority.WRITE, client=client)
                for bus in self.buses
            )
        )

    async def _execute_split(
        self, route: Route, pdu: bytes, parts: list[bytes], client: str, priority: Priority
    ) -> bytes:
        """Send the parts in order; the first exception fails the whole with the drive's code."""
        replies: list[bytes] = []
        for part in parts:
            reply = await self._send(route, part, client, priority)
            if is_exception(reply):
                return reply
            replies.append(reply)
        return join_replies(pdu, replies)


def _to_ram(pdu: bytes, ram_address: Callable[[int], int]) -> bytes:
    """Rewrite the register address of a 06H/10H write to its RAM-only twin."""
    if pdu[0] in (WRITE_SINGLE_REGISTER, WRITE_MULTIPLE_REGISTERS) and len(pdu) >= 5:
        (register,) = struct.unpack(">H", pdu[1:3])
        ram = ram_address(register)
        if ram != register:
            return pdu[:1] + struct.pack(">H", ram) + pdu[3:]
    return pdu
