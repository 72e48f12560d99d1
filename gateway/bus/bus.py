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
from bisect import bisect_left
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import StrEnum
from functools import partial
from typing import Any, NamedTuple

from gateway.backoff import Backoff
from gateway.bus.exchange import Stray
from gateway.bus.gap_excess import GapExcess
from gateway.bus.health import HealthTracker
from gateway.bus.late_replies import LateReplies
from gateway.bus.line import Exchange, LineSettings, Sending, SerialLine
from gateway.bus.line_share import LineShares
from gateway.bus.queue import USE_OF_PRIORITY, Priority, RequestQueue, Transaction, Waiter
from gateway.bus.wakeup import woken_or_timeout
from gateway.errors import (
    BadReply,
    BusClosed,
    BusFailed,
    DriveOffline,
    GatewayError,
    GatewayTargetFailed,
    LineError,
    ModbusError,
    PortError,
    ReplyTimeout,
)
from gateway.logs import FRAMES, FRAMES_CACHED, dump_frame, frame_dump_enabled
from gateway.modbus.functions import lookup
from gateway.modbus.rtu import BROADCAST_ADDRESS, build_frame, request_frame
from gateway.tasks import cancel_and_wait

log = logging.getLogger(__name__)

# What a probe asks for, as the traffic monitor shows it: on the wire, a probe is a marker (08H
# echo or a read the drive answered before: `gateway.bus.late_replies`), never assumed optional.
PROBE_PDU = bytes.fromhex("0800000000")
PROBE_CLIENT = "probe"
RESYNC_CLIENT = "resync"
"""The traffic monitor's client of a marker sent before a request (`gateway.bus.late_replies`)."""
IDLE_WAKE_S = 0.5
"""With nothing queued, the bus still wakes this often to see whether a probe is due."""
FINISH_S = 5.0
"""At shutdown, how long the transaction on the wire may take to finish before it is cut off."""


class BusState(StrEnum):
    OPENING = "opening"
    OPEN = "open"
    REOPENING = "reopening"
    CLOSED = "closed"


# Enum members read per transaction, as module globals (see `gateway.bus.queue`: a member read
# costs ~950 instructions on Python 3.11, a global ~45).
_OPEN, _CLOSED = BusState.OPEN, BusState.CLOSED
_READ = Priority.READ
_DEBUG = logging.DEBUG


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


@dataclass(slots=True)
class DriveStats:
    """The line's counters for one address (0: broadcasts), for metrics to read at scrape time."""

    transactions: int = 0
    retries: int = 0
    timeouts: int = 0
    bad_replies: Counter[str] = field(default_factory=Counter)
    exceptions: Counter[int] = field(default_factory=Counter)
    failed: int = 0
    late_replies: int = 0
    """Replies that came after their request had timed out, set aside (`LateReplies`)."""
    resyncs: int = 0
    """Diagnostic echoes sent after a timeout before anything else went to this drive."""
    line_s: float = 0.0
    """Time the line was held for this address, timeouts included: a dead drive's cost shows."""


@dataclass(slots=True)
class BusStats:
    """Counters a dashboard or the benchmark reads; plain numbers, written by the bus only.

    What happened on the wire is counted once, for the address it happened with (`drives`); the
    bus's totals of those counters are their sums, worked out when read (a scrape), not kept.
    """

    drives: dict[int, DriveStats] = field(default_factory=dict)
    requests: int = 0
    broadcasts: int = 0
    coalesced: int = 0
    queue_full: int = 0
    offline_rejected: int = 0
    port_errors: int = 0
    reopens: int = 0
    busy_s: float = 0.0
    min_gap_s: float | None = None

    @property
    def transactions(self) -> int:
        return sum(drive.transactions for drive in self.drives.values())

    @property
    def retries(self) -> int:
        return sum(drive.retries for drive in self.drives.values())

    @property
    def timeouts(self) -> int:
        return sum(drive.timeouts for drive in self.drives.values())

    @property
    def bad_replies(self) -> Counter[str]:
        return sum((drive.bad_replies for drive in self.drives.values()), Counter())

    @property
    def exceptions(self) -> Counter[int]:
        return sum((drive.exceptions for drive in self.drives.values()), Counter())

    @property
    def failed(self) -> int:
        return sum(drive.failed for drive in self.drives.values())

    @property
    def late_replies(self) -> int:
        return sum(drive.late_replies for drive in self.drives.values())

    @property
    def resyncs(self) -> int:
        return sum(drive.resyncs for drive in self.drives.values())


# Immutable, and built per transaction: a NamedTuple costs a fraction of a frozen dataclass,
# whose __init__ goes through object.__setattr__ for every field.
class RequestDone(NamedTuple):
    """One caller's request, answered: what metrics count and time per source and function."""

    bus: str
    address: int
    function: int
    client: str
    duration_s: float
    """From `request()` to its answer: queue wait, retries and time on the wire."""
    code: int | None
    """None for a normal reply, else the exception code the caller got (the drive's, 0AH, 0BH)."""


Outcome = tuple[Callable[..., None], tuple[Any, ...]]
"""What the event loop does with a finished transaction: a callback and its arguments."""
DriveListener = Callable[[str, int, bool], None]
"""Called on the event loop with (bus name, address, online) when a drive goes offline or back."""
RequestObserver = Callable[[str, int, int, str, float, int | None], None]
"""Called on the event loop with a `RequestDone`'s fields, in its order (bus, address, function,
client, duration_s, code), when a caller's request is answered: as arguments, not a record,
because it runs once per request and most observers (metrics) only add numbers; an observer
that keeps the request makes the `RequestDone` itself (`RequestDone(*fields)`)."""
PortListener = Callable[[str, str, bool, str], None]
"""Called on the event loop with (bus name, port, lost, reason) when the port is lost (or can't
be opened at start) and when it is open again."""
Tap = Callable[[str, Transaction, int, float, "Exchange | LineError"], None]
"""Told of every attempt on the wire while set (the console's traffic monitor): bus name, the
transaction, the attempt (0: first), when it started (monotonic) and what came of it."""


class Bus:
    def __init__(self, settings: BusSettings, line: SerialLine | None = None) -> None:
        self.settings = settings
        self.name = settings.name
        self.line = line or SerialLine(settings.line)
        self.state = BusState.OPENING
        self.stats = BusStats()
        self.drive_stats = self.stats.drives
        self.gap_excess = GapExcess()
        """The silence beyond the inter-frame gap before each back-to-back request: our share."""
        self._reply_heard_at = 0.0
        """When the last transaction's reply ended; 0.0 when it had none (a broadcast, a
        timeout) or the gap's end has picked (or found nothing) since."""
        self._back_to_back = False
        """The transaction carried now was found waiting by the gap's end after a reply: the
        silence beyond t3.5 before it is the gateway's own."""
        self.health = HealthTracker(
            settings.offline_after, settings.probe_initial_s, settings.probe_max_s
        )
        self._queue = RequestQueue(settings.queue_size, settings.shares)
        self._charge_share = self._queue.charge_share
        self._work: asyncio.Future[None] | None = None
        """Set while the bus waits for work; a new request (or a lost port) resolves it."""
        self._carrying: Transaction | None = None
        """The transaction taken from the queue (`_pick`, at the gap's end) until it is answered:
        on the wire, or about to be. Whoever holds the bus must answer it, whatever happens."""
        self.late_replies = LateReplies(self.name)
        self._heard_from_carried = False
        """A frame from the drive carried now was set aside during its transaction: it is
        there, late or out of step, and its failure doesn't count towards offline."""
        # Frames the line heard between transactions (late replies that came after every
        # drain) are accounted in the ledger as any set aside during an attempt.
        self.line.receiver.on_set_aside = self._set_aside_between
        self._answered_frames = self.late_replies.answered
        """The ledger's last answered request per drive (`LateReplies.answered`), bound once."""
        self._marker_sent: bytes | None = None
        """The marker `_pick` sent in place of `_carrying`'s frame (a probe's, or its drive
        owes replies): `_execute` reads its answer."""
        self._loop: asyncio.AbstractEventLoop | None = None
        self.line.on_port_error = self._wake
        self._listeners: list[DriveListener] = []
        self._request_observers: list[RequestObserver] = []
        self._report_own = self._report_transaction
        """`Transaction.observed_by` of the reads `submit_read` queues: bound once, not once
        per request."""
        self._port_listeners: list[PortListener] = []
        self._opened = asyncio.Event()
        self._idle = asyncio.Event()
        self._idle_awaited = 0
        """`wait_idle` calls waiting now: a transaction answered in the reader callback sets
        `_idle` only then (the event is cleared before each wait)."""
        self._last_port_error = ""
        self.tap: Tap | None = None
        """None unless someone watches the traffic: then one attribute test per attempt."""

    def add_listener(self, listener: DriveListener) -> None:
        self._listeners.append(listener)

    def add_port_listener(self, listener: PortListener) -> None:
        self._port_listeners.append(listener)

    def add_request_observer(self, observer: RequestObserver) -> None:
        self._request_observers.append(observer)

    def remove_request_observer(self, observer: RequestObserver) -> None:
        if observer in self._request_observers:
            self._request_observers.remove(observer)

    def take_listeners(self, old: Bus) -> None:
        """A reload reopened `old`'s line as this bus: whoever listened to it listens here."""
        self._listeners = list(old._listeners)
        self._port_listeners = list(old._port_listeners)
        self._request_observers = list(old._request_observers)
        self.tap = old.tap

    @property
    def queue_depth(self) -> int:
        return len(self._queue)

    @property
    def reads_waiting(self) -> bool:
        """Client reads wait for the line (`RequestQueue.reads_waiting`): the poller cuts a
        long poll short then."""
        return self._queue.reads_waiting

    @property
    def busy(self) -> bool:
        """A transaction is on the wire. Not a `BusState`: the state is what the line is (a
        metric and the console show it), not a flicker per transaction."""
        return self._carrying is not None

    @property
    def closing(self) -> bool:
        return self.state is _CLOSED

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
        self.submit(
            address,
            pdu,
            waiter,
            priority=priority,
            client=client,
            timeout_s=timeout_s,
            retries=retries,
        )
        return await waiter

    def submit(
        self,
        address: int,
        pdu: bytes,
        waiter: Waiter,
        *,
        priority: Priority,
        client: str,
        timeout_s: float | None = None,
        retries: int | None = None,
    ) -> None:
        """Queue `pdu` for the drive at `address`; `waiter` gets the reply PDU (None for a
        broadcast) or the error, as `request` would return or raise it.

        Synchronous: a caller that answers from `waiter` itself (the Modbus-TCP server's reads)
        costs no task and no pass of the event loop between its request and the queue. A
        refusal before queueing (closed, offline, queue full) is raised here, not given to
        `waiter`.
        """
        observed = None
        if self._request_observers:
            waiter = observed = _Observed(self, waiter, address, pdu, client, time.monotonic())
        settings = self.settings
        try:
            self._admit(address)
            self._put(
                Transaction(
                    address,
                    pdu,
                    priority,
                    client,
                    settings.timeout_s if timeout_s is None else timeout_s,
                    settings.retries if retries is None else retries,
                    address != BROADCAST_ADDRESS and bool(pdu) and lookup(pdu[0]).coalescable,
                    [waiter],
                )
            )
        except ModbusError as exc:
            if observed is not None:
                observed.report(exc.code)
            raise
        self.line.fire_due()  # a gap that ended while this loop pass ran: act on it now

    def submit_read(
        self,
        address: int,
        pdu: bytes,
        waiter: Waiter,
        client: str,
        timeout_s: float | None,
        retries: int | None,
        coalescable: bool,
    ) -> None:
        """`submit` of a client's read (READ priority) in one call, for the Modbus-TCP fast
        path (`Router.submit`): `coalescable` is the caller's `lookup(pdu[0]).coalescable`.

        The common case is written out here: the bus open, its port not being reopened, the
        drive not offline, not a broadcast. Anything else takes `submit`, which refuses it or
        queues it the same way."""
        if (
            self.state is not _OPEN
            or self._work is not None
            or address == BROADCAST_ADDRESS
            or (self.health.offline_count and self.health.is_offline(address))
        ):
            self.submit(
                address,
                pdu,
                waiter,
                priority=Priority.READ,
                client=client,
                timeout_s=timeout_s,
                retries=retries,
            )
            return
        stats = self.stats
        stats.requests += 1
        # One clock read: the request's start for the observers is when it was queued.
        now = time.monotonic()
        # The observers are told of this waiter's outcome by the transaction itself (no
        # `_Observed` around the waiter: one object less per request).
        observed_by = self._report_own if self._request_observers else None
        settings = self.settings
        transaction = Transaction(
            address,
            pdu,
            _READ,
            client,
            settings.timeout_s if timeout_s is None else timeout_s,
            settings.retries if retries is None else retries,
            coalescable,
            [waiter],
            False,
            b"",
            now,
            observed_by,
        )
        try:
            carrier = self._queue.put(transaction)
        except ModbusError as exc:  # the queue is full (QueueFull, as `_put` counts it)
            stats.queue_full += 1
            if observed_by is not None:
                self._report(address, pdu, client, now, exc.code)
            raise
        if carrier is transaction:
            # Framed now, while the line may be busy: no CRC work in the gap.
            transaction.frame = request_frame(address, pdu)
        else:
            stats.coalesced += 1
            if observed_by is not None:
                # Its waiter joined the queued transaction's (the last one there): the
                # observers are told of it by a wrapper of its own from now.
                carrier.waiters[-1] = _Observed(self, waiter, address, pdu, client, now)
        # `_wake` without a `_work` to resolve (tested above), then `fire_due`: an idle line
        # sends it now, and a gap that ended while this loop pass ran is acted on now.
        self.line.queued()

    def _admit(self, address: int) -> None:
        """Raise the refusal a request to `address` gets before it is queued, if any."""
        self.stats.requests += 1
        if self.state is BusState.CLOSED:
            raise BusClosed(f"bus {self.name} is shutting down")
        if self.state is BusState.REOPENING:
            raise GatewayTargetFailed(f"bus {self.name}: {self._last_port_error}")
        if address != BROADCAST_ADDRESS and self.health.is_offline(address):
            self.stats.offline_rejected += 1
            raise DriveOffline(f"drive {address} on {self.name} is offline")

    def _put(self, transaction: Transaction) -> None:
        transaction.queued_at = time.monotonic()
        try:
            carrier = self._queue.put(transaction)
        except GatewayError:
            self.stats.queue_full += 1
            raise
        if carrier is transaction:
            # Framed now, while the line may be busy: no CRC work in the gap.
            transaction.frame = request_frame(transaction.address, transaction.pdu)
        else:
            self.stats.coalesced += 1
        self._wake()

    def _report_transaction(self, transaction: Transaction, code: int | None) -> None:
        """A transaction's own waiter has its outcome (`Transaction.observed_by`)."""
        self._report(
            transaction.address, transaction.pdu, transaction.client, transaction.queued_at, code
        )

    def _report(
        self, address: int, pdu: bytes, client: str, started: float, code: int | None
    ) -> None:
        function, duration_s = pdu[0] if pdu else 0, time.monotonic() - started
        for observer in self._request_observers:
            try:
                observer(self.name, address, function, client, duration_s, code)
            except Exception:
                log.exception("bus %s: request observer failed", self.name)

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
        self.state = BusState.CLOSED
        queued = self._queue.take_all()
        self._wake()
        error = BusClosed(f"bus {self.name} {reason}")
        for transaction in queued:
            _fail(transaction, error)

    async def wait_idle(self, timeout_s: float) -> None:
        """Wait (at most `timeout_s`) for the transaction on the wire to finish."""
        if not self.busy:
            return
        self._idle.clear()
        self._idle_awaited += 1
        try:
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._idle.wait(), timeout_s)
        finally:
            self._idle_awaited -= 1

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
                    outcome = await self._execute(transaction, sending)
                except Exception as exc:  # a bug costs this one request, never the line
                    log.exception("bus %s: unexpected error in a transaction", self.name)
                    error = GatewayTargetFailed(f"bus {self.name}: {exc}")
                    outcome = (_fail, (transaction, error))
                self._finish(transaction, sending, outcome)
        except BaseException:
            # Cancelled or died holding a transaction taken from the queue (on the wire, or
            # chosen at the gap's end): answer it, nobody else will.
            if self._carrying is not None:
                self._done(_fail, (self._carrying, BusClosed(f"bus {self.name} stopped")))
            raise
        finally:
            self.line.close()

    def _finish(self, transaction: Transaction, sending: Sending, outcome: Outcome) -> None:
        """Charge the line's time to the transaction's kind of work, and tell its waiters."""
        now = time.monotonic()
        held = max(now, self.line.busy_until) - sending.started
        self._queue.charge(transaction, held, now)
        self._done(*outcome)

    def _done(self, callback: Callable[..., None], args: tuple[Any, ...]) -> None:
        """A transaction taken from the queue is over: tell its waiters, and `wait_idle`."""
        self._carrying = None
        self._marker_sent = None
        callback(*args)
        self._idle.set()

    async def _start_next(self) -> tuple[Transaction, Sending] | None:
        """Keep the inter-frame gap, then send the best transaction there is at its end.

        The choice is made in the wake-up that ends the gap (`SerialLine.send_after_gap` calls
        `_pick` there, a learnt lead of up to a few hundred microseconds before the gap's end):
        a write that arrives during the gap, before then, still goes first, identical reads that
        arrive during it join the one transaction, and the frame leaves without another pass of
        the event loop. With nothing queued, the bus waits for work.
        """
        # Every pass, not only when idle: a busy line must still find out a drive is back.
        self._queue_due_probes()
        while not self.closing:
            try:
                sending = await self.line.send_after_gap(
                    self._pick, self._reply_within, self._replied, self._idle_for
                )
            except PortError as exc:
                picked = self._carrying
                if picked is not None:  # taken from the queue, but the port failed under it
                    self._done(_fail, (picked, GatewayTargetFailed(f"bus {self.name}: {exc}")))
                self._port_lost(exc)
                return None
            except Exception as exc:  # a bug in choosing or framing costs that one request
                picked = self._carrying
                if picked is None:
                    raise  # nothing was taken: trying again would spin; let the bus fail
                log.exception("bus %s: unexpected error starting a transaction", self.name)
                self._done(_fail, (picked, GatewayTargetFailed(f"bus {self.name}: {exc}")))
                continue
            if sending is not None:
                transaction = self._carrying
                assert transaction is not None  # a frame went out, so `_pick` chose one
                return transaction, sending
            if self.closing:
                return None
            if len(self._queue):
                # Queued after the gap's end found nothing, before this coroutine resumed: its
                # wake-up found nobody waiting, so look again rather than sleep on it.
                continue
            # The line has been idle for `_idle_for` (the caller held while it was: a request
            # queued meanwhile went out at once, `_wake`).
            if not self.line.is_open or self.line.failed:
                return None  # the port went while idle: reopen it first
            self._queue_due_probes()
        return None

    def _pick(self) -> bytes | None:
        """Take the best transaction queued now and return its frame; None if there is none."""
        # The first pick after a reply is the gap's end: what it finds waited for the line, and
        # the silence before it, beyond the gap, is the gateway's own (`_observe_gap`). That
        # includes a request queued during the gap (clients answered together ask again
        # together) and one queued after the gap had ended but before the gateway woke for it
        # (it waited for the gateway: leaving it out would hide the late wake-ups). When that
        # pick finds nothing, the line goes idle and the next request waited for nobody (a
        # client's think time). After a broadcast or a timeout there is no reply to count from.
        reply_heard_at = self._reply_heard_at
        self._reply_heard_at = 0.0
        if self.state is _CLOSED:  # `closing`, without the property's call
            return None
        get_nowait = self._queue.get_nowait
        while (transaction := get_nowait()) is not None:
            probe = transaction.probe
            if not probe:
                # `Transaction.wanted`, written out (once per transaction): does anyone still
                # wait for it? Every waiter gone (clients disconnected): no bus time for it.
                for waiter in transaction.waiters:
                    if not waiter.done():
                        break
                else:
                    continue
            address = transaction.address
            if (
                address != BROADCAST_ADDRESS
                and not probe
                and self.health.offline_count  # none offline (the usual case): no call
                and self.health.is_offline(address)
            ):  # went offline while this waited: 0BH at once, without bus time
                self.stats.offline_rejected += 1
                _fail(transaction, DriveOffline(f"drive {address} on {self.name} is offline"))
                continue
            self._carrying = transaction  # before anything can fail: it must be answered
            self._back_to_back = reply_heard_at != 0.0
            if probe or address in self.late_replies.owing:
                # A marker first (a probe is one): `_execute` reads its answer, the frames
                # before it set aside, then sends the request (`gateway.bus.late_replies`).
                self._marker_sent = self.late_replies.marker(address)
                return self._marker_sent
            return transaction.frame or build_frame(address, transaction.pdu)
        return None

    def _set_aside_between(self, frames: tuple[Stray, ...]) -> None:
        """The receiver's `on_set_aside`: frames heard between transactions."""
        self._set_aside(frames, self.settings.timeout_s)

    def _idle_for(self) -> float | None:
        """With nothing queued at a gap's end: how long the line may wait, idle, for a request
        (`_wake` sends one queued meanwhile at once); None once the bus is closing."""
        if self.closing:
            return None
        next_probe = self.health.next_probe_at()
        wait = IDLE_WAKE_S if next_probe is None else next_probe - time.monotonic()
        return min(max(wait, 0.001), IDLE_WAKE_S)

    def _reply_within(self) -> float | None:
        """For the transaction `_pick` just sent: how long its drive has to answer (None: a
        broadcast, which has no reply)."""
        carrying = self._carrying
        if carrying is None or carrying.address == BROADCAST_ADDRESS or self._marker_sent:
            return None  # an echo after a timeout is read by `_execute`, never by the hold
        return carrying.timeout_s

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
                if self.state is BusState.OPENING:
                    self._notify_port(True, str(exc))  # missing from the start: lost too
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
                self._notify_port(False, "")
            if self.closing:
                return
            self.state = BusState.OPEN
            log.info("bus %s: %s open", self.name, self.settings.line.port)
            self._opened.set()
            return

    async def _execute(self, transaction: Transaction, first: Sending) -> Outcome:
        """Carry one transaction through its attempts, the first already sent; what to tell
        its waiters.

        An attempt to a drive that owes replies (or is unsure, `gateway.bus.late_replies`)
        starts with a marker; a probe is a marker and nothing else. Every frame set aside on
        the way is accounted in the ledger (`_set_aside`), and every frame whose reply was not
        taken (a timeout, a bad reply) is owed from then on.
        """
        address = transaction.address
        frame = first.frame
        broadcast = address == BROADCAST_ADDRESS
        late = self.late_replies
        self._observe_gap(first)
        # A probe brings its own retries; a drive that just failed gets none.
        retries = transaction.retries
        cut = not transaction.probe and self.health.is_suspect(address)
        if cut:
            retries = 0
        drive = self._drive(address)
        errors: list[LineError] = []
        # The first attempt is on its way: the request itself, or the marker that brings its
        # drive back in step (`_pick`).
        pending: Sending | None = first
        marker_pending: Sending | None = None
        if self._marker_sent is not None:
            frame = transaction.frame or build_frame(address, transaction.pdu)
            self._marker_sent = None
            marker_pending, pending = first, None
        sends = 0  # times the request itself went out (markers aside): a write's may be done
        self._heard_from_carried = False
        attempt = -1
        while attempt < retries:
            attempt += 1
            if attempt:
                drive.retries += 1
            on_its_way = marker_pending or pending
            started = on_its_way.started if on_its_way is not None else time.monotonic()
            on_wire = frame
            try:
                if transaction.probe or (
                    not broadcast and late.needs_marker(address, frame, transaction)
                ):
                    sent, marker_pending = marker_pending, None  # taken, whatever comes of it
                    if sent is None:
                        sent = await self.line.send_after_gap(partial(late.marker, address))
                        assert sent is not None  # the pick always has a frame
                    on_wire = sent.frame
                    if transaction.probe:  # what the traffic monitor shows of it
                        transaction.pdu = on_wire[1:-2]
                    marker = await self._catch_up(transaction, sent, drive)
                    if transaction.probe:  # the marker is all a probe asks
                        return self._attempt_answered(transaction, attempt, started, marker, drive)
                    started = time.monotonic()
                    on_wire = frame
                self._count_attempt(drive, frame)
                sends += 1
                sending, pending = pending, None
                if sending is not None:
                    exchange = await self.line.finish(
                        sending, expect_reply=not broadcast, timeout_s=transaction.timeout_s
                    )
                else:
                    exchange = await self.line.transact(
                        frame, expect_reply=not broadcast, timeout_s=transaction.timeout_s
                    )
                if exchange.strays and self._set_aside(exchange.strays, transaction.timeout_s):
                    # A frame from the asked drive came before this reply and answered nothing
                    # it owed: this reply may be an older request's. Never handed over.
                    raise BadReply("out_of_step", f"drive {address} sent a frame out of step")
            except ReplyTimeout as exc:
                drive.timeouts += 1
                self._unanswered(address, on_wire, started, exc.strays, transaction.timeout_s)
                dump_frame(self.name, "rx timeout", exc.received)
                errors.append(exc)
                if self.tap is not None:
                    self.tap(self.name, transaction, attempt, started, exc)
                continue
            except BadReply as exc:
                drive.bad_replies[exc.kind] += 1
                self._unanswered(address, on_wire, started, exc.strays, transaction.timeout_s)
                if cut:  # something came back: not a dead drive's, its retries are due
                    retries, cut = transaction.retries, False
                dump_frame(self.name, f"rx bad {exc.kind}", exc.frame)
                log.debug("bus %s: %s", self.name, exc)
                errors.append(exc)
                if self.tap is not None:
                    self.tap(self.name, transaction, attempt, started, exc)
                continue
            except PortError as exc:
                if self.tap is not None:
                    self.tap(self.name, transaction, attempt, started, exc)
                if not broadcast:  # its reply may come to the reopened port
                    late.unanswered(address, on_wire, started, transaction)
                self._port_lost(exc)
                return _fail, (transaction, GatewayTargetFailed(f"bus {self.name}: {exc}"))
            finally:
                drive.line_s += time.monotonic() - started
            return self._attempt_answered(transaction, attempt, started, exchange, drive)
        drive.failed += 1
        log.debug("bus %s: drive %d: every attempt failed: %s", self.name, address, errors)
        # A probe that got nothing usable counts as a failure whatever went wrong, so its drive
        # backs off; a request that got bad replies proves its drive is there.
        # A drive heard meanwhile (late replies, set aside) is there too: not a failure.
        if not self._heard_from_carried and (
            transaction.probe or all(isinstance(error, ReplyTimeout) for error in errors)
        ):
            self._failed(address)
        message = f"drive {address} on {self.name}: {errors[-1]}"
        unconfirmed = sends if transaction.pdu and lookup(transaction.pdu[0]).writes else 0
        if unconfirmed and not broadcast:
            message += (
                f"; the write may have been carried out all the same: it went out {sends} "
                f"time{'s' if sends > 1 else ''} and no reply confirmed it"
            )
            log.warning("bus %s: %s", self.name, message)
        error = GatewayTargetFailed(message)
        error.sent_unconfirmed = unconfirmed
        return _fail, (transaction, error)

    async def _catch_up(
        self, transaction: Transaction, sent: Sending, drive: DriveStats
    ) -> Exchange:
        """Read the answer to the marker `sent` (`gateway.bus.late_replies`), the frames before
        it set aside: its drive is in step once it is back. Raises as an attempt does
        (ReplyTimeout when the answer doesn't come in time, BadReply)."""
        address, timeout_s = transaction.address, transaction.timeout_s
        late = self.late_replies
        self._count_attempt(drive, sent.frame)
        drive.resyncs += 1
        try:
            exchange = await self.line.finish(
                sent, expect_reply=True, timeout_s=timeout_s, owed=late.owed_frames(address)
            )
        except LineError as exc:
            late.marker_missed(address, sent.frame)
            self._tap_marker(transaction, sent, exc)
            raise  # its line time is the attempt's (`_execute`)
        self._tap_marker(transaction, sent, exchange)
        drive.line_s += time.monotonic() - sent.started
        self._set_aside(exchange.strays, timeout_s)
        late.caught_up(address, sent.frame, exchange.reply_pdu or b"")
        self._record(exchange, drive)
        return exchange

    def _tap_marker(
        self, transaction: Transaction, sent: Sending, outcome: Exchange | LineError
    ) -> None:
        """Show the traffic monitor a marker as what it is: its own request, client `resync`,
        before the request it brought its drive in step for. A probe is its marker (its
        attempt is shown as the probe's, with the marker's request: `_pick`)."""
        if self.tap is not None and not transaction.probe:
            marker = Transaction(
                transaction.address,
                sent.frame[1:-2],
                _READ,
                RESYNC_CLIENT,
                transaction.timeout_s,
                0,
            )
            self.tap(self.name, marker, 0, sent.started, outcome)

    def _unanswered(
        self,
        address: int,
        frame: bytes,
        sent_at: float,
        strays: tuple[Stray, ...],
        timeout_s: float,
    ) -> None:
        """An attempt ended without its reply: `frame` is owed (its reply may still come),
        then the frames set aside are accounted (one of them may be that very reply)."""
        if address != BROADCAST_ADDRESS:
            self.late_replies.unanswered(address, frame, sent_at, self._carrying)
        self._set_aside(strays, timeout_s)

    def _set_aside(self, strays: tuple[Stray, ...], timeout_s: float) -> bool:
        """Account frames set aside during an attempt in the ledger, each for the drive that
        sent it; True if the drive carried now is left owing or unsure by them."""
        late = self.late_replies
        carrying = self._carrying
        asked = carrying.address if carrying is not None else BROADCAST_ADDRESS
        for frame, heard_at in strays:
            address = frame[0]
            dump_frame(self.name, "rx set aside", frame)
            asked_at = late.heard(frame)
            if address == asked:
                self._heard_from_carried = True
            if asked_at is None:
                # It answers nothing its drive owed: a reply that contradicts the request, or
                # another address's, counted for the drive asked (as a bad reply always was).
                if asked == BROADCAST_ADDRESS:  # heard between transactions
                    self._drive(address).bad_replies["out_of_step"] += 1
                else:
                    kind = "mismatch" if address == asked else "address"
                    self._drive(asked).bad_replies[kind] += 1
            else:
                self._drive(address).late_replies += 1
                late.seen(address, heard_at, timeout_s, asked_at)
            if self.health.offline_count and self.health.is_offline(address):
                # It answers again: probe it now, not at the end of its backoff.
                self.health.probe_now(address, time.monotonic())
        if carrying is None or asked not in late.owing:
            return False
        frame = carrying.frame or build_frame(asked, carrying.pdu)
        return late.needs_marker(asked, frame, carrying)

    def _replied(self, sending: Sending, pdu: bytes, heard_at: float) -> None:
        """The line's reader callback has the whole and valid reply to the frame `_pick` chose:
        the transaction ends there, as `_execute` would end it, without the bus's coroutine
        (one pass of the event loop less per transaction). A timeout, a bad, partial or late
        reply, retries: those go the coroutine's way (`_execute`).

        Once per transaction on a busy line, so what `_execute`, `_finish` and `_done` do for
        an answered first attempt is written out here in one place (`_observe_gap`,
        `_count_attempt`, `_attempt_answered`, `_record`, `_resolve`): the same counts, the
        same values for the observers. Never a broadcast (no reply is held for one).
        """
        transaction = self._carrying
        assert transaction is not None  # the line holds a reply to what `_pick` chose
        started = sending.started
        gap_s = sending.gap_s
        failure: GatewayError | None = None
        try:
            if self._back_to_back:  # `_observe_gap`
                beyond_gap = gap_s - self.settings.line.gap_s
                since_queued = started - transaction.queued_at
                excess = beyond_gap if beyond_gap < since_queued else since_queued
                histogram = self.gap_excess  # `Buckets.observe`, written out
                histogram.counts[bisect_left(histogram.bounds, excess)] += 1
                histogram.sum_s += excess
            address = transaction.address
            drive = self.drive_stats.get(address)
            if drive is None:
                drive = self._drive(address)
            drive.transactions += 1
            now = time.monotonic()
            # The line is quiet since the reply's last byte, heard before now: what `_finish`
            # charges, max(now, busy_until) - started, is this too.
            held = now - started
            drive.line_s += held
            if FRAMES_CACHED(_DEBUG) is not False and FRAMES.isEnabledFor(_DEBUG):
                dump_frame(self.name, "tx", sending.frame)
                # The frame as it came: a reply that passed its CRC check rebuilds byte-exact.
                dump_frame(self.name, "rx", build_frame(address, pdu))
            stats = self.stats  # `_record`
            stats.busy_s += heard_at - started
            self._reply_heard_at = heard_at
            min_gap_s = stats.min_gap_s
            if min_gap_s is None or gap_s < min_gap_s:
                stats.min_gap_s = gap_s
            if pdu[0] & 0x80 and len(pdu) > 1:
                drive.exceptions[pdu[1]] += 1
            if self.tap is not None:  # the exchange made only for it
                exchange = Exchange(pdu, gap_s, heard_at - started, heard_at)
                self.tap(self.name, transaction, 0, started, exchange)
            if address not in self.health.answering:
                self._answered(address)  # back, or its failures to forget
                # What a marker may be made from: a request it answered (the first since it
                # last failed is as good as the last, and costs the common case nothing).
                self._answered_frames[address] = sending.frame
        except Exception as exc:  # a bug costs this one request, never the line
            log.exception("bus %s: unexpected error in a transaction", self.name)
            failure = GatewayTargetFailed(f"bus {self.name}: {exc}")
            now = time.monotonic()
            held = max(now, self.line.busy_until) - started
        # `RequestQueue.charge`, written out (a reply: never a broadcast).
        self._charge_share(USE_OF_PRIORITY[transaction.priority], held, now)
        self._carrying = None  # `_done`
        self._marker_sent = None
        if failure is not None:
            _fail(transaction, failure)
        else:
            # `_resolve`, with the report to the observers of the transaction's own waiter
            # (`Transaction.observed_by`, `_report`) written out, timed at `now`.
            observed = transaction.observed_by is not None
            for waiter in transaction.waiters:
                if type(waiter) is _Observed:
                    waiter.answer(pdu)
                elif not waiter.done():
                    if observed:
                        request = transaction.pdu
                        function = request[0] if request else 0
                        client = transaction.client
                        duration_s = now - transaction.queued_at
                        code = pdu[1] if pdu[0] & 0x80 and len(pdu) > 1 else None
                        for observer in self._request_observers:
                            try:
                                observer(self.name, address, function, client, duration_s, code)
                            except Exception:
                                log.exception("bus %s: request observer failed", self.name)
                    waiter.set_result(pdu)
                observed = False
        if self._idle_awaited:
            self._idle.set()
        # What `_start_next` does before each gap: a busy line must still find a drive is back.
        if self.health.offline_count:
            self._queue_due_probes()

    def _observe_gap(self, sending: Sending) -> None:
        """The silence the gateway added before `sending`, for a transaction the gap's end
        found waiting: beyond the gap, or since the request was queued if that came later (the
        line was idle until then for want of a request, not of the gateway)."""
        if self._back_to_back:
            transaction = self._carrying
            assert transaction is not None  # `sending` is its frame
            beyond_gap = sending.gap_s - self.settings.line.gap_s
            since_queued = sending.started - transaction.queued_at
            self.gap_excess.observe(beyond_gap if beyond_gap < since_queued else since_queued)

    def _count_attempt(self, drive: DriveStats, frame: bytes) -> None:
        """One attempt on the wire, whichever way it ends (`_execute` or `_replied`)."""
        drive.transactions += 1
        dump_frame(self.name, "tx", frame)

    def _drive(self, address: int) -> DriveStats:
        drive = self.drive_stats.get(address)
        if drive is None:
            drive = self.drive_stats[address] = DriveStats()
        return drive

    def _attempt_answered(
        self,
        transaction: Transaction,
        attempt: int,
        started: float,
        exchange: Exchange,
        drive: DriveStats,
    ) -> Outcome:
        """An attempt got its reply (or a broadcast went out): count it, tell the health
        tracker and the traffic monitor; the waiters get the reply."""
        address = transaction.address
        if exchange.reply_pdu is not None and frame_dump_enabled():
            # The frame as it came: a reply that passed its CRC check rebuilds byte-exact.
            dump_frame(self.name, "rx", build_frame(address, exchange.reply_pdu))
        self._record(exchange, drive)
        if self.tap is not None:
            self.tap(self.name, transaction, attempt, started, exchange)
        if address == BROADCAST_ADDRESS:
            self.stats.broadcasts += 1
            self.late_replies.broadcast()
        else:
            self._answered(address)
            if not transaction.probe:
                frame = transaction.frame or build_frame(address, transaction.pdu)
                self._answered_frames[address] = frame  # what a marker may be made from
        return _resolve, (transaction, exchange.reply_pdu)

    def _record(self, exchange: Exchange, drive: DriveStats) -> None:
        self.stats.busy_s += exchange.busy_s
        self._reply_heard_at = exchange.reply_heard_at
        if self.stats.min_gap_s is None or exchange.gap_s < self.stats.min_gap_s:
            self.stats.min_gap_s = exchange.gap_s
        pdu = exchange.reply_pdu
        if pdu and pdu[0] & 0x80 and len(pdu) > 1:
            drive.exceptions[pdu[1]] += 1

    def _answered(self, address: int) -> None:
        if self.health.record_answer(address):
            log.warning("bus %s: drive %d is back online", self.name, address)
            self._notify(address, True)

    def _failed(self, address: int) -> None:
        if self.health.record_failure(address, time.monotonic()):
            log.warning(
                "bus %s: drive %d offline after %d failed requests; probing it with backoff",
                self.name,
                address,
                self.settings.offline_after,
            )
            self._notify(address, False)

    def _port_lost(self, exc: PortError) -> None:
        self.stats.port_errors += 1
        self._last_port_error = str(exc)
        self._reply_heard_at = 0.0  # the reopened line's first gap follows no reply
        if not self.closing:
            self.state = BusState.REOPENING
        log.error("bus %s: port lost (%s); reopening with backoff", self.name, exc)
        self._notify_port(True, str(exc))
        queued = self._queue.take_all()
        error = GatewayTargetFailed(f"bus {self.name}: {exc}")
        for transaction in queued:
            _fail(transaction, error)
        # No drive on this line can be reached now: say so (MQTT availability, metrics); once
        # the port is back, the probes find each one again.
        now = time.monotonic()
        for address in self.health.known_addresses():
            if self.health.force_offline(address, now):
                self._notify(address, False)

    def _queue_due_probes(self) -> None:
        """Queue one probe for each offline drive whose backoff is over: a single attempt, or
        the bus's retries for a drive that went offline only because the port did.

        A probe has no waiter: the health tracker reads its outcome.
        """
        if not self.health.any_offline or self.state is not _OPEN:
            return
        now = time.monotonic()
        for address in self.health.due_probes(now):
            self.health.postpone_probe(address, now)
            probe = Transaction(
                address=address,
                pdu=PROBE_PDU,
                priority=Priority.READ,
                client=PROBE_CLIENT,
                timeout_s=self.settings.timeout_s,
                retries=self.settings.retries if self.health.lost_with_line(address) else 0,
                probe=True,
                # A probe that comes due again while the last one still waits joins it: a long
                # queue after a reopen must not fill with copies, each costing its timeouts.
                coalescable=True,
                frame=build_frame(address, PROBE_PDU),
                queued_at=time.monotonic(),
            )
            try:
                self._queue.put(probe)
            except GatewayError:
                return

    # -- telling the others --------------------------------------------------------------------

    def _notify_port(self, lost: bool, reason: str) -> None:
        for listener in self._port_listeners:
            try:
                listener(self.name, self.settings.line.port, lost, reason)
            except Exception:
                log.exception("bus %s: port listener failed", self.name)

    def _notify(self, address: int, online: bool) -> None:
        for listener in self._listeners:
            try:
                listener(self.name, address, online)
            except Exception:
                log.exception("bus %s: drive listener failed", self.name)


class _Observed:
    """A waiter whose outcome the bus's request observers (metrics, the console) are told of,
    with the time from `submit` to the answer."""

    __slots__ = ("_address", "_bus", "_client", "_pdu", "_started", "_waiter", "done")

    def __init__(
        self, bus: Bus, waiter: Waiter, address: int, pdu: bytes, client: str, started: float
    ) -> None:
        self._bus = bus
        self._waiter = waiter
        self.done = waiter.done
        """The waiter's own: asked once or twice per request, without a call of ours between."""
        self._address = address
        self._pdu = pdu
        self._client = client
        self._started = started

    def set_result(self, result: bytes | None, /) -> None:
        code = _exception_code(result)
        self._bus._report(self._address, self._pdu, self._client, self._started, code)
        self._waiter.set_result(result)

    def answer(self, result: bytes | None) -> None:
        """`_resolve`'s `done` and `set_result` in one call, for a transaction answered in the
        reader callback (`Bus._replied`): nothing once the waiter is done (its client gone),
        else the observers told, then the waiter."""
        waiter = self._waiter
        if waiter.done():
            return
        code = _exception_code(result)
        bus, pdu = self._bus, self._pdu
        function, duration_s = pdu[0] if pdu else 0, time.monotonic() - self._started
        for observer in bus._request_observers:  # `Bus._report`, written out
            try:
                observer(bus.name, self._address, function, self._client, duration_s, code)
            except Exception:
                log.exception("bus %s: request observer failed", bus.name)
        waiter.set_result(result)

    def set_exception(self, exception: BaseException, /) -> None:
        self.report(exception.code if isinstance(exception, ModbusError) else None)
        self._waiter.set_exception(exception)

    def report(self, code: int | None) -> None:
        self._bus._report(self._address, self._pdu, self._client, self._started, code)


def _exception_code(reply: bytes | None) -> int | None:
    """The exception code a caller answered with `reply` got, for the request observers; None
    for a normal reply (or a broadcast's none). `Bus._replied` writes it out."""
    return reply[1] if reply is not None and len(reply) > 1 and reply[0] & 0x80 else None


def _resolve(transaction: Transaction, reply: bytes | None) -> None:
    report = transaction.observed_by  # for its own waiter, the first
    for waiter in transaction.waiters:
        if not waiter.done():
            if report is not None:
                report(transaction, _exception_code(reply))
            waiter.set_result(reply)
        report = None


def _fail(transaction: Transaction, error: GatewayError) -> None:
    report = transaction.observed_by  # for its own waiter, the first
    for waiter in transaction.waiters:
        if not waiter.done():
            if report is not None:
                report(transaction, error.code if isinstance(error, ModbusError) else None)
            waiter.set_exception(error)
        report = None
