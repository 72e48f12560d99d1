"""The bus: one owner per RS-485 line, one transaction at a time, timeout and retry policy.

The asyncio side decides what goes on the wire and when (queue, priorities, dead drives, retries);
a single worker thread per bus does the wire work with exact timing (`gateway.bus.line`). Buses
run independently of each other: each has its own queue, thread and port.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import random
import time
from collections import Counter
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from enum import StrEnum
from functools import partial

from gateway.bus.health import HealthTracker
from gateway.bus.line import Exchange, LineSettings, SerialLine
from gateway.bus.queue import Priority, RequestQueue, Transaction
from gateway.errors import (
    BadReply,
    DriveOffline,
    GatewayError,
    GatewayTargetFailed,
    LineError,
    PortError,
    ReplyTimeout,
)
from gateway.modbus.functions import PURE_READS
from gateway.modbus.rtu import BROADCAST_ADDRESS, build_frame

log = logging.getLogger(__name__)

# 08H diagnosis, sub-function 0000 (return query data): every Modbus device that implements 08H
# echoes it, and one that doesn't still answers exception 01H, which proves it is alive as well.
PROBE_PDU = bytes.fromhex("0800000000")
PROBE_CLIENT = "probe"


class BusState(StrEnum):
    OPENING = "opening"
    OPEN = "open"
    REOPENING = "reopening"
    CLOSED = "closed"


@dataclass(frozen=True, slots=True)
class BusSettings:
    name: str
    line: LineSettings
    timeout_s: float = 0.3
    retries: int = 2
    queue_size: int = 256
    offline_after: int = 3
    probe_initial_s: float = 1.0
    probe_max_s: float = 30.0
    reopen_initial_s: float = 0.5
    reopen_max_s: float = 10.0


@dataclass(slots=True)
class BusStats:
    """Counters a dashboard or the benchmark reads; plain ints, updated on the event loop."""

    requests: int = 0
    transactions: int = 0
    retries: int = 0
    timeouts: int = 0
    bad_replies: Counter[str] = field(default_factory=Counter)
    exceptions: Counter[int] = field(default_factory=Counter)
    failed: int = 0
    broadcasts: int = 0
    coalesced: int = 0
    queue_full: int = 0
    offline_rejected: int = 0
    port_errors: int = 0
    reopens: int = 0
    busy_s: float = 0.0
    min_gap_s: float | None = None


DriveListener = Callable[[str, int, bool], None]
"""Called with (bus name, address, online) when a drive goes offline or comes back."""


class Bus:
    def __init__(self, settings: BusSettings, line: SerialLine | None = None) -> None:
        self.settings = settings
        self.name = settings.name
        self.line = line or SerialLine(settings.line)
        self.state = BusState.OPENING
        self.stats = BusStats()
        self.health = HealthTracker(
            settings.offline_after, settings.probe_initial_s, settings.probe_max_s
        )
        self._queue = RequestQueue(settings.queue_size)
        self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix=f"bus-{self.name}")
        self._listeners: list[DriveListener] = []
        self._opened = asyncio.Event()
        self._idle = asyncio.Event()
        self._idle.set()
        self._last_port_error = ""

    @property
    def _closed(self) -> bool:
        # A property, not an inline comparison: `state` changes across awaits.
        return self.state is BusState.CLOSED

    def add_listener(self, listener: DriveListener) -> None:
        self._listeners.append(listener)

    @property
    def queue_depth(self) -> int:
        return len(self._queue)

    # -- what callers use --------------------------------------------------------------------

    async def request(
        self,
        address: int,
        pdu: bytes,
        *,
        priority: Priority,
        client: str,
        timeout_s: float | None = None,
        retries: int | None = None,
    ) -> bytes | None:
        """Send `pdu` to the drive at `address`; return the reply PDU (None for a broadcast).

        A drive's exception comes back as its exception PDU, byte-exact. Raises
        GatewayTargetFailed (0x0B) or GatewayPathUnavailable (0x0A, queue full).
        """
        self.stats.requests += 1
        if self.state is BusState.CLOSED:
            raise GatewayTargetFailed(f"bus {self.name} is shutting down")
        if self.state is BusState.REOPENING:
            raise GatewayTargetFailed(f"bus {self.name}: {self._last_port_error}")
        if address != BROADCAST_ADDRESS and self.health.is_offline(address):
            self.stats.offline_rejected += 1
            raise DriveOffline(f"drive {address} on {self.name} is offline")
        waiter: asyncio.Future[bytes | None] = asyncio.get_running_loop().create_future()
        transaction = Transaction(
            address=address,
            pdu=pdu,
            priority=priority,
            client=client,
            timeout_s=self.settings.timeout_s if timeout_s is None else timeout_s,
            retries=self.settings.retries if retries is None else retries,
            coalescable=address != BROADCAST_ADDRESS and bool(pdu) and pdu[0] in PURE_READS,
            waiters=[waiter],
        )
        try:
            carrier = self._queue.put(transaction)
        except GatewayError:
            self.stats.queue_full += 1
            raise
        if carrier is not transaction:
            self.stats.coalesced += 1
        return await waiter

    # -- lifecycle ---------------------------------------------------------------------------

    async def run(self) -> None:
        """Own the port until cancelled: open it, serve the queue, probe offline drives."""
        try:
            async with asyncio.TaskGroup() as tasks:
                tasks.create_task(self._serve(), name=f"bus:{self.name}:serve")
                tasks.create_task(self._probe_offline(), name=f"bus:{self.name}:probe")
        finally:
            self.state = BusState.CLOSED
            self._fail_queued(GatewayTargetFailed(f"bus {self.name} stopped"))
            await asyncio.get_running_loop().run_in_executor(self._executor, self.line.close)
            self._executor.shutdown(wait=False)

    async def wait_open(self, timeout_s: float) -> bool:
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(self._opened.wait(), timeout_s)
        return self._opened.is_set()

    def close(self) -> None:
        """Refuse new requests and answer queued ones with 0x0B; the one on the wire finishes."""
        self.state = BusState.CLOSED
        self._fail_queued(GatewayTargetFailed(f"bus {self.name} is shutting down"))

    async def wait_idle(self, timeout_s: float) -> None:
        """Wait (at most `timeout_s`) for the transaction on the wire to finish."""
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(self._idle.wait(), timeout_s)

    # -- the worker --------------------------------------------------------------------------

    async def _serve(self) -> None:
        loop = asyncio.get_running_loop()
        while self.state is not BusState.CLOSED:
            if not self.line.is_open:
                await self._open_with_backoff()
                continue
            transaction = await self._queue.get()
            if not transaction.wanted:
                continue
            self._idle.clear()
            try:
                await self._execute(loop, transaction)
            finally:
                self._idle.set()

    async def _open_with_backoff(self) -> None:
        delay = self.settings.reopen_initial_s
        loop = asyncio.get_running_loop()
        failures = 0
        while not self._closed:
            try:
                await loop.run_in_executor(self._executor, self.line.open)
            except PortError as exc:
                failures += 1
                self._last_port_error = str(exc)
                if self.state is not BusState.CLOSED:
                    self.state = BusState.REOPENING
                # Say it loudly once, then quietly: a missing adapter shouldn't flood the journal.
                level = logging.WARNING if failures == 1 else logging.DEBUG
                log.log(level, "bus %s: %s; retrying (attempt %d)", self.name, exc, failures)
                await asyncio.sleep(delay * random.uniform(0.8, 1.2))
                delay = min(delay * 2, self.settings.reopen_max_s)
                continue
            if self.state is BusState.REOPENING:
                self.stats.reopens += 1
            if self._closed:
                await loop.run_in_executor(self._executor, self.line.close)
                return
            self.state = BusState.OPEN
            log.info("bus %s: %s open", self.name, self.settings.line.port)
            self._opened.set()
            return

    async def _execute(self, loop: asyncio.AbstractEventLoop, transaction: Transaction) -> None:
        address = transaction.address
        is_probe = transaction.client == PROBE_CLIENT
        if address != BROADCAST_ADDRESS and not is_probe and self.health.is_offline(address):
            self.stats.offline_rejected += 1
            self._fail(transaction, DriveOffline(f"drive {address} on {self.name} is offline"))
            return
        frame = build_frame(address, transaction.pdu)
        broadcast = address == BROADCAST_ADDRESS
        retries = 0 if self.health.is_suspect(address) else transaction.retries
        errors: list[LineError] = []
        for attempt in range(retries + 1):
            if attempt:
                self.stats.retries += 1
            transact = partial(
                self.line.transact,
                frame,
                expect_reply=not broadcast,
                timeout_s=transaction.timeout_s,
            )
            self.stats.transactions += 1
            try:
                exchange = await loop.run_in_executor(self._executor, transact)
            except ReplyTimeout as exc:
                self.stats.timeouts += 1
                errors.append(exc)
                continue
            except BadReply as exc:
                self.stats.bad_replies[exc.kind] += 1
                log.debug("bus %s: %s", self.name, exc)
                errors.append(exc)
                continue
            except PortError as exc:
                self._port_lost(exc)
                self._fail(transaction, GatewayTargetFailed(f"bus {self.name}: {exc}"))
                return
            self._record(exchange)
            if broadcast:
                self.stats.broadcasts += 1
            else:
                self._answered(address)
            self._resolve(transaction, exchange.reply_pdu)
            return
        self.stats.failed += 1
        if all(isinstance(error, ReplyTimeout) for error in errors):
            self._failed(address)
        self._fail(
            transaction, GatewayTargetFailed(f"drive {address} on {self.name}: {errors[-1]}")
        )

    def _record(self, exchange: Exchange) -> None:
        self.stats.busy_s += exchange.busy_s
        if self.stats.min_gap_s is None or exchange.gap_s < self.stats.min_gap_s:
            self.stats.min_gap_s = exchange.gap_s
        pdu = exchange.reply_pdu
        if pdu and pdu[0] & 0x80 and len(pdu) > 1:
            self.stats.exceptions[pdu[1]] += 1

    def _answered(self, address: int) -> None:
        if self.health.record_answer(address):
            log.warning("bus %s: drive %d is back online", self.name, address)
            self._notify(address, online=True)

    def _failed(self, address: int) -> None:
        if self.health.record_failure(address, time.monotonic()):
            log.warning(
                "bus %s: drive %d offline after %d failed requests; probing it with backoff",
                self.name,
                address,
                self.settings.offline_after,
            )
            self._notify(address, online=False)

    def _notify(self, address: int, *, online: bool) -> None:
        for listener in self._listeners:
            try:
                listener(self.name, address, online)
            except Exception:
                log.exception("bus %s: drive listener failed", self.name)

    def _port_lost(self, exc: PortError) -> None:
        self.stats.port_errors += 1
        self._last_port_error = str(exc)
        if self.state is not BusState.CLOSED:
            self.state = BusState.REOPENING
        log.error("bus %s: port lost (%s); reopening with backoff", self.name, exc)
        self._fail_queued(GatewayTargetFailed(f"bus {self.name}: {exc}"))

    async def _probe_offline(self) -> None:
        """Send one single-attempt probe to each offline drive when its backoff is due."""
        while self.state is not BusState.CLOSED:
            now = time.monotonic()
            for address in self.health.due_probes(now):
                self.health.postpone_probe(address, now)
                if self.state is BusState.OPEN:
                    self._queue_probe(address)
            next_at = self.health.next_probe_at()
            wait = 0.5 if next_at is None else min(max(next_at - now, 0.01), 0.5)
            await asyncio.sleep(wait)

    def _queue_probe(self, address: int) -> None:
        probe: asyncio.Future[bytes | None] = asyncio.get_running_loop().create_future()
        # Nobody awaits a probe; its outcome is read by the health tracker, not from here.
        probe.add_done_callback(lambda f: f.cancelled() or f.exception())
        with contextlib.suppress(GatewayError):
            self._queue.put(
                Transaction(
                    address=address,
                    pdu=PROBE_PDU,
                    priority=Priority.READ,
                    client=PROBE_CLIENT,
                    timeout_s=self.settings.timeout_s,
                    retries=0,
                    waiters=[probe],
                )
            )

    # -- answering waiters -------------------------------------------------------------------

    @staticmethod
    def _resolve(transaction: Transaction, reply: bytes | None) -> None:
        for waiter in transaction.waiters:
            if not waiter.done():
                waiter.set_result(reply)

    @staticmethod
    def _fail(transaction: Transaction, error: GatewayError) -> None:
        for waiter in transaction.waiters:
            if not waiter.done():
                waiter.set_exception(error)

    def _fail_queued(self, error: GatewayError) -> None:
        for transaction in self._queue.take_all():
            self._fail(transaction, error)
