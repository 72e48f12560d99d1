"""The bus: one owner per RS-485 line, one transaction at a time, timeout and retry policy.

Callers put requests into the bus's queue (`request()`); the bus's own coroutine takes them out
one at a time and does the wire work with exact timing (`gateway.bus.line`). Everything runs on
the event loop: the port's descriptor is watched by the loop and the inter-frame gap ends on an
exact timer, so no thread, lock or hand-over between threads is needed, and a transaction costs
the process no more wake-ups than the line itself makes.

The bus takes the next transaction as late as it can: in the wake-up that ends the inter-frame
gap after the previous one, where its frame is written too (that wake-up comes a learnt lead of
up to a few hundred microseconds before the gap's end, `gateway.bus.gap_lead`). A write that
arrives during the gap, before that wake-up, still goes first, and identical reads that arrive
during it join the one transaction; one that arrives in that last lead waits one transaction
more.
Buses are independent of each other: each has its own queue, coroutine and port.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from dataclasses import dataclass, field

from gateway.backoff import Backoff
from gateway.bus.carrier import Carrier
from gateway.bus.dispatch import BusState as BusState
from gateway.bus.dispatch import Dispatch
from gateway.bus.exchange import Sending
from gateway.bus.health import HealthTracker
from gateway.bus.line import LineSettings, SerialLine
from gateway.bus.line_share import LineShares
from gateway.bus.observers import RESYNC_CLIENT as RESYNC_CLIENT
from gateway.bus.observers import (
    BusObservers,
    DriveListener,
    Observed,
    Outcome,
    PortListener,
    RequestObserver,
    Tap,
    give,
)
from gateway.bus.queue import Priority, RequestQueue, Transaction, Waiter
from gateway.bus.stats import BusStats as BusStats
from gateway.bus.stats import DriveStats as DriveStats
from gateway.bus.stats import RequestDone as RequestDone
from gateway.bus.wakeup import woken_or_timeout
from gateway.errors import (
    BusClosed,
    BusFailed,
    DriveOffline,
    GatewayTargetFailed,
    ModbusError,
    PortError,
    QueueFull,
)
from gateway.modbus.functions import lookup
from gateway.modbus.rtu import BROADCAST_ADDRESS, request_frame
from gateway.tasks import cancel_and_wait

log = logging.getLogger(__name__)

FINISH_S = 5.0
"""At shutdown, how long the transaction on the wire may take to finish before it is cut off."""


# Enum members read per transaction, as module globals (see `gateway.bus.queue`: a member read
# costs ~950 instructions on Python 3.11, a global ~45).
_OPEN, _CLOSED = BusState.OPEN, BusState.CLOSED


@dataclass(frozen=True, slots=True)
class BusSettings:
    name: str
    line: LineSettings
    timeout_s: float = 0.3
    retries: int = 2
    queue_size: int = 256
    offline_after: int = 3
    probe_initial_s: float = 2.0
    probe_max_s: float = 30.0
    reopen_initial_s: float = 0.5
    reopen_max_s: float = 10.0
    shares: LineShares = field(default_factory=LineShares)
    """While reads wait, the most of the line's time writes and broadcasts may take."""


class Bus:
    """One RS-485 line's owner: its queue, its port's life, and the transaction on the wire
    (carried through its attempts by its `Carrier`)."""

    def __init__(self, settings: BusSettings, line: SerialLine | None = None) -> None:
        self.settings = settings
        self.name = settings.name
        self.line = line or SerialLine(settings.line)
        self.stats = BusStats()
        self.drive_stats = self.stats.drives
        self.health = HealthTracker(
            settings.offline_after, settings.probe_initial_s, settings.probe_max_s
        )
        self.observers = BusObservers(self.name)
        self._queue = RequestQueue(settings.queue_size, settings.shares)
        self.carrier = carrier = Carrier(
            self.name,
            settings.line,
            self.line,
            self._queue,
            self.stats,
            self.health,
            self.observers,
        )
        self.late_replies = carrier.late_replies
        self.gap_excess = carrier.gap_excess
        self.dispatch = Dispatch(
            self.name,
            self._queue,
            carrier,
            self.health,
            self.stats,
            settings.timeout_s,
            settings.retries,
        )
        self._work: asyncio.Future[None] | None = None
        """Set while the bus waits for work; a new request (or a lost port) resolves it."""
        # Frames the line heard between transactions (late replies that came after every
        # drain) are accounted in the ledger as any set aside during an attempt.
        self.line.receiver.on_set_aside = carrier.set_aside
        self.line.on_port_error = self._wake
        self._loop: asyncio.AbstractEventLoop | None = None
        self._opened = asyncio.Event()
        self._last_port_error = ""
        self._closed_for = "is shutting down"  # why `close` refuses requests from then on

    def add_listener(self, listener: DriveListener) -> None:
        self.observers.drive_listeners.append(listener)

    def add_port_listener(self, listener: PortListener) -> None:
        self.observers.port_listeners.append(listener)

    def add_request_observer(self, observer: RequestObserver) -> None:
        self.observers.request_observers.append(observer)

    def remove_request_observer(self, observer: RequestObserver) -> None:
        if observer in self.observers.request_observers:
            self.observers.request_observers.remove(observer)

    def take_listeners(self, old: Bus) -> None:
        """A reload reopened `old`'s line as this bus: whoever listened to it listens here."""
        self.observers.take(old.observers)

    @property
    def tap(self) -> Tap | None:
        """The traffic monitor's tap (`BusObservers.tap`): told of every attempt while set."""
        return self.observers.tap

    @tap.setter
    def tap(self, tap: Tap | None) -> None:
        self.observers.tap = tap

    @property
    def queue_depth(self) -> int:
        return len(self._queue)

    @property
    def reads_waiting(self) -> bool:
        """Client reads wait for the line: the poller cuts a long poll short then."""
        return self._queue.reads_waiting

    @property
    def busy(self) -> bool:
        """A transaction is on the wire. Not a `BusState`: the state is what the line is (a
        metric and the console show it), not a flicker per transaction."""
        return self.carrier.carrying is not None

    @property
    def state(self) -> BusState:
        """What the line is (its `Dispatch` picks for an open one only)."""
        return self.dispatch.state

    @state.setter
    def state(self, state: BusState) -> None:
        self.dispatch.state = state

    @property
    def closing(self) -> bool:
        return self.dispatch.state is _CLOSED

    # -- what callers use (event loop) ---------------------------------------------------------

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
        waiter: asyncio.Future[bytes | None] = asyncio.get_running_loop().create_future()
        self.submit(address, pdu, waiter, priority, client, timeout_s, retries)
        return await waiter

    def submit(
        self,
        address: int,
        pdu: bytes,
        waiter: Waiter,
        priority: Priority,
        client: str,
        timeout_s: float | None = None,
        retries: int | None = None,
        coalescable: bool | None = None,
    ) -> None:
        """Queue `pdu` for the drive at `address`; `waiter` gets the reply PDU (None for a
        broadcast) or the error, as `request` would return or raise it.

        Synchronous: a caller that answers from `waiter` itself (the Modbus-TCP server's reads)
        costs no task and no pass of the event loop between its request and the queue. A
        refusal before queueing (closed, offline, queue full) is raised here, not given to
        `waiter`, and told to the request observers as its answer. `coalescable`: the
        caller's `lookup(pdu[0]).coalescable` when it has it (None: looked up here).
        """
        stats = self.stats
        stats.requests += 1
        now = time.monotonic()  # the request's start, for the observers
        observed_by = self.observers if self.observers.request_observers else None
        settings = self.settings
        try:
            if self.dispatch.state is not _OPEN or self.health.offline_count:
                self._admit(address)
            transaction = Transaction(
                address,
                pdu,
                priority,
                client,
                settings.timeout_s if timeout_s is None else timeout_s,
                settings.retries if retries is None else retries,
                address != BROADCAST_ADDRESS
                and bool(pdu)
                and (lookup(pdu[0]).coalescable if coalescable is None else coalescable),
                [waiter],
                False,
                b"",
                now,
                observed_by,
            )
            carrier = self._queue.put(transaction)
        except ModbusError as exc:
            if isinstance(exc, QueueFull):
                stats.queue_full += 1
            if observed_by is not None:
                self.observers.report(address, pdu, client, now, None, exc.code)
            raise
        if carrier is transaction:
            # Framed now, while the line may be busy: no CRC work in the gap.
            transaction.frame = request_frame(address, pdu)
        else:
            stats.coalesced += 1
            if observed_by is not None:
                # Its waiter joined the queued transaction's (the last one there): the
                # observers are told of it by a wrapper of its own from now.
                carrier.waiters[-1] = Observed(self.observers, waiter, address, pdu, client, now)
        if self._work is not None:  # the bus's coroutine waits for work (reopening the port)
            self._wake()
        # An idle line sends it now; a gap ended in this pass is acted on (`GapKeeper.queued`).
        queued = self.line.queued  # a callable attribute: read, then called (port.py says why)
        queued()

    def _admit(self, address: int) -> None:
        """Raise the refusal a request to `address` gets before it is queued, if any."""
        if self.state is BusState.CLOSED:
            raise BusClosed(f"bus {self.name} {self._closed_for}")
        if self.state is BusState.REOPENING:
            raise GatewayTargetFailed(f"bus {self.name}: {self._last_port_error}")
        if address != BROADCAST_ADDRESS and self.health.is_offline(address):
            self.stats.offline_rejected += 1
            raise DriveOffline(f"drive {address} on {self.name} is offline")

    # -- lifecycle (event loop) ----------------------------------------------------------------

    async def run(self) -> None:
        """Own the port until cancelled or closed: open it, serve the queue, probe."""
        self._loop = asyncio.get_running_loop()
        serving = self._loop.create_task(self._serve(), name=f"bus-{self.name}")
        try:
            # Shielded: cancelling run() must not cut a transaction off halfway on the wire.
            await asyncio.shield(serving)
        except asyncio.CancelledError:
            self.close()
            done, _ = await asyncio.wait({serving}, timeout=FINISH_S)
            if not done:
                await cancel_and_wait(serving, 1.0)
            raise
        finally:
            if serving.done() and not serving.cancelled() and serving.exception() is not None:
                failure = serving.exception()
                self.close()  # nothing will serve the queue now: answer it, refuse the rest
                log.critical("bus %s: died", self.name, exc_info=failure)
                # A bus that can't serve its line must not look alive: fail the service, so
                # systemd or Docker restarts it (Restart=on-failure), rather than answer 0BH
                # forever.
                raise BusFailed(f"bus {self.name}: died: {failure!r}") from failure

    async def wait_open(self, timeout_s: float) -> bool:
        try:
            await asyncio.wait_for(self._opened.wait(), timeout_s)
        except TimeoutError:
            return False
        return True

    def close(self, reason: str = "is shutting down") -> None:
        """Refuse new requests and answer queued ones with 0x0B; the one on the wire finishes."""
        self.state, self._closed_for = BusState.CLOSED, reason
        queued = self._queue.take_all()
        self._wake()
        error = BusClosed(f"bus {self.name} {reason}")
        for transaction in queued:
            give(transaction, error)

    async def wait_idle(self, timeout_s: float) -> None:
        """Wait (at most `timeout_s`) for the transaction on the wire to finish."""
        if not self.busy:
            return
        carrier = self.carrier
        carrier.idle.clear()
        carrier.idle_awaited += 1
        try:
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(carrier.idle.wait(), timeout_s)
        finally:
            carrier.idle_awaited -= 1

    # -- the bus's coroutine -------------------------------------------------------------------

    async def _serve(self) -> None:
        try:
            while not self.closing:
                if not self.line.is_open:
                    await self._open_with_backoff()
                    continue
                started = await self._start_next()
                if started is None:
                    continue
                transaction, sending = started
                outcome: Outcome
                try:
                    outcome = await self.carrier.carry(transaction, sending)
                except PortError as exc:
                    self._port_lost(exc)
                    outcome = GatewayTargetFailed(f"bus {self.name}: {exc}")
                except Exception as exc:  # a bug costs this one request, never the line
                    outcome = self.carrier.bug(transaction, exc)
                self.carrier.finish(transaction, outcome, sending.started)
        except BaseException:
            # Cancelled or died holding a transaction taken from the queue (on the wire, or
            # chosen at the gap's end): answer it, nobody else will.
            carrying = self.carrier.carrying
            if carrying is not None:
                stopped = BusClosed(f"bus {self.name} stopped")
                self.carrier.finish(carrying, stopped, None)
            raise
        finally:
            self.line.close()

    async def _start_next(self) -> tuple[Transaction, Sending] | None:
        """Keep the inter-frame gap, then send the best transaction there is at its end.

        The choice is made in the wake-up that ends the gap (`SerialLine.send_after_gap` asks
        the bus's `Dispatch` there, a learnt lead of up to a few hundred microseconds before the
        gap's end): a write that arrives during the gap, before then, still goes first,
        identical reads that arrive during it join the one transaction, and the frame leaves
        without another pass of the event loop. With nothing queued, the bus waits for work.
        """
        # Every pass, not only when idle: a busy line must still find out a drive is back.
        dispatch = self.dispatch
        dispatch.queue_due_probes()
        while not self.closing:
            try:
                sending = await self.line.send_after_gap(dispatch)
            except PortError as exc:
                picked = self.carrier.carrying
                if picked is not None:  # taken from the queue, but the port failed under it
                    error = GatewayTargetFailed(f"bus {self.name}: {exc}")
                    self.carrier.finish(picked, error, None)
                self._port_lost(exc)
                return None
            except Exception as exc:  # a bug in choosing or framing costs that one request
                picked = self.carrier.carrying
                if picked is None:
                    raise  # nothing was taken: trying again would spin; let the bus fail
                log.exception("bus %s: unexpected error starting a transaction", self.name)
                error = GatewayTargetFailed(f"bus {self.name}: {exc}")
                self.carrier.finish(picked, error, None)
                continue
            if sending is not None:
                transaction = self.carrier.carrying
                assert transaction is not None  # a frame went out, so the dispatch chose one
                return transaction, sending
            if self.closing:
                return None
            if len(self._queue):
                # Queued after the gap's end found nothing, before this coroutine resumed: its
                # wake-up found nobody waiting, so look again rather than sleep on it.
                continue
            # The line has been idle for `Dispatch.idle_for` (the caller held while it was: a
            # request queued meanwhile went out at once, `_wake`).
            if not self.line.is_open or self.line.failed:
                return None  # the port went while idle: reopen it first
            dispatch.queue_due_probes()
        return None

    async def _wait_for_work(self, timeout_s: float) -> None:
        assert self._loop is not None
        work = self._work = self._loop.create_future()
        try:
            await woken_or_timeout(work, timeout_s)
        finally:
            if self._work is work:
                self._work = None

    def _wake(self) -> None:
        """Something for the bus to do: a request, a lost port, shutdown."""
        work = self._work
        if work is not None and not work.done():
            work.set_result(None)
        # An idle line sends a request queued now in this very callback (`GapKeeper.kick`);
        # a lost port or shutdown releases it to the bus's loop.
        self.line.kick()

    async def _open_with_backoff(self) -> None:
        backoff = Backoff(self.settings.reopen_initial_s, self.settings.reopen_max_s)
        failures = 0
        while not self.closing:
            try:
                self.line.open()
            except PortError as exc:
                failures += 1
                self._last_port_error = str(exc)
                if self.state is BusState.OPENING:  # missing from the start: lost too
                    self.observers.port(self.settings.line.port, True, str(exc))
                if not self.closing:
                    self.state = BusState.REOPENING
                # Say it loudly once, then quietly: a missing adapter shouldn't flood the journal.
                level = logging.WARNING if failures == 1 else logging.DEBUG
                log.log(level, "bus %s: %s; retrying (attempt %d)", self.name, exc, failures)
                # Only shutdown cuts the wait short: requests arriving meanwhile are refused
                # (0BH) or queued, and must not turn the backoff into a retry per request.
                until = time.monotonic() + backoff.next_delay()
                while not self.closing and (left := until - time.monotonic()) > 0:
                    await self._wait_for_work(left)
                continue
            if self.state is BusState.REOPENING:
                self.stats.reopens += 1
                self.health.line_back(time.monotonic())
                self.observers.port(self.settings.line.port, False, "")
            if self.closing:
                return
            self.state = BusState.OPEN
            log.info("bus %s: %s open", self.name, self.settings.line.port)
            self._opened.set()
            return

    def _port_lost(self, exc: PortError) -> None:
        if self.closing:  # closed under it (shutdown, another master heard): no port lost
            return  # `close` answered the queue; nothing to tell listeners or drives
        self.stats.port_errors += 1
        self._last_port_error = str(exc)
        self.carrier.reply_heard_at = 0.0  # the reopened line's first gap follows no reply
        self.state = BusState.REOPENING
        log.error("bus %s: port lost (%s); reopening with backoff", self.name, exc)
        self.observers.port(self.settings.line.port, True, str(exc))
        queued = self._queue.take_all()
        error = GatewayTargetFailed(f"bus {self.name}: {exc}")
        for transaction in queued:
            give(transaction, error)
        # No drive on this line can be reached now: say so (MQTT availability, metrics); once
        # the port is back, the probes find each one again.
        now = time.monotonic()
        for address in self.health.known_addresses():
            if self.health.force_offline(address, now):
                self.observers.drive(address, False)
