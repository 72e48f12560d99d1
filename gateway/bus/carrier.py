"""One transaction carried through its attempts on the wire, and each attempt judged.

The bus (`gateway.bus.bus`) owns the queue and the line's life; the carrier takes the
transaction the bus picked and has on the wire, and works out what its waiters get:
- an attempt whose reply is whole and valid is answered (`attempt_answered`), wherever it ends:
  in the port's reader callback (`Dispatch.replied`, for a first attempt the line finished
  there) or in the bus's coroutine (`carry`, for everything else: retries, timeouts, bad
  replies, markers, broadcasts). Both count, record and tell the same things through the same
  calls;
- an attempt to a drive that owes replies starts with a marker (`gateway.bus.late_replies`),
  whose answer brings it back in step (`_catch_up`); a probe is a marker and nothing else;
- every frame set aside on the way is accounted in the ledger (`set_aside`), and every frame
  whose reply was not taken is owed from then on (`_unanswered`).
"""

from __future__ import annotations

import asyncio
import logging
import time

from gateway.bus.exchange import Exchange, Sending, Stray
from gateway.bus.gap_excess import GapExcess
from gateway.bus.health import HealthTracker
from gateway.bus.late_replies import LateReplies
from gateway.bus.line import SerialLine
from gateway.bus.line_settings import LineSettings
from gateway.bus.line_user import OneFrame
from gateway.bus.observers import BusObservers, Outcome, give
from gateway.bus.queue import RequestQueue, Transaction
from gateway.bus.stats import BusStats, DriveStats
from gateway.errors import BadReply, GatewayTargetFailed, LineError, PortError, ReplyTimeout
from gateway.logs import FRAMES_CACHED, dump_frame, frame_dump_enabled
from gateway.modbus.functions import lookup
from gateway.modbus.rtu import BROADCAST_ADDRESS, build_frame

log = logging.getLogger("gateway.bus.bus")

_DEBUG = logging.DEBUG


class Carrier:
    """Carries the bus's transactions, one at a time, through their attempts on one line."""

    def __init__(
        self,
        name: str,
        line_settings: LineSettings,
        line: SerialLine,
        queue: RequestQueue,
        stats: BusStats,
        health: HealthTracker,
        observers: BusObservers,
    ) -> None:
        self.name = name
        self.line_settings = line_settings
        self.line = line
        self._receiver = line.receiver
        self._charge_share = queue.charge_share
        """The bus's queue's line-time meter: charged with each transaction's time on the
        line, to its `use` (`finish`)."""
        self.stats = stats
        self.drive_stats = stats.drives
        self.health = health
        self.observers = observers
        self.late_replies = LateReplies(name)
        self._answered_frames = self.late_replies.answered
        """The ledger's last answered request per drive (`LateReplies.answered`), bound once."""
        self.gap_excess = GapExcess()
        """The silence beyond the inter-frame gap before each back-to-back request: our share."""
        self.carrying: Transaction | None = None
        """The transaction taken from the queue (`Dispatch.pick`, at the gap's end) until it
        is answered: on the wire, or about to be. Whoever holds it must answer it."""
        self.marker_sent: bytes | None = None
        """The marker sent in place of `carrying`'s frame (a probe's, or its drive owes
        replies): `carry` reads its answer."""
        self.reply_heard_at = 0.0
        """When the last transaction's reply ended; 0.0 when it had none (a broadcast, a
        timeout) or the gap's end has picked (or found nothing) since."""
        self.back_to_back = False
        """The transaction carried now was found waiting by the gap's end after a reply: the
        silence beyond t3.5 before it is the gateway's own."""
        self._heard_from_carried = False
        """A frame from the drive carried now was set aside during its transaction: it is
        there, late or out of step, and its failure doesn't count towards offline."""
        self.idle = asyncio.Event()
        """Set as a transaction ends while anyone waits for that (`idle_awaited`, the bus's
        `wait_idle`, which clears it before each wait)."""
        self.idle_awaited = 0

    def drive(self, address: int) -> DriveStats:
        drive = self.drive_stats.get(address)
        if drive is None:
            drive = self.drive_stats[address] = DriveStats()
        return drive

    def finish(self, transaction: Transaction, outcome: Outcome, started: float | None) -> None:
        """A transaction taken from the queue is over, whichever way: charge the line's time
        since `started` (None: it never went out) to its kind of work, tell its waiters and
        `idle`. The one place a transaction ends."""
        self.carrying = None
        self.marker_sent = None
        if started is not None:
            now = time.monotonic()
            quiet_since = self._receiver.quiet_since  # `SerialLine.busy_until`
            held = (quiet_since if quiet_since > now else now) - started
            # A callable attribute: read, then called (a method call's lookup of it is
            # generic on Python 3.11, a plain read is specialised).
            charge = self._charge_share
            charge(transaction.use, held, now)
        give(transaction, outcome)
        if self.idle_awaited:
            self.idle.set()

    def bug(self, transaction: Transaction, exc: Exception) -> Outcome:
        """A bug in carrying `transaction` costs it, never the line: logged, answered 0BH."""
        log.exception("bus %s: unexpected error in a transaction", self.name)
        return GatewayTargetFailed(f"bus {self.name}: {exc}")

    # -- every attempt, in the bus's coroutine ---------------------------------------------------

    async def carry(self, transaction: Transaction, first: Sending) -> Outcome:
        """Carry `transaction` through its attempts, the first already sent; what to tell its
        waiters. Raises PortError (the port is lost: the bus reopens it), after counting what
        went out as owed."""
        address = transaction.address
        frame = first.frame
        broadcast = address == BROADCAST_ADDRESS
        late = self.late_replies
        observers = self.observers
        drive = self.drive(address)
        self.sent(drive, first.frame, first)
        # A probe brings its own retries; a drive that just failed gets none.
        retries = transaction.retries
        cut = not transaction.probe and self.health.is_suspect(address)
        if cut:
            retries = 0
        errors: list[LineError] = []
        # The first attempt is on its way: the request itself, or the marker that brings its
        # drive back in step (`Dispatch.pick`).
        pending: Sending | None = first
        marker_pending: Sending | None = None
        if self.marker_sent is not None:
            frame = transaction.frame or build_frame(address, transaction.pdu)
            self.marker_sent = None
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
            exchange: Exchange | None = None  # None once the attempt has failed
            try:
                if transaction.probe or (
                    not broadcast and late.needs_marker(address, frame, transaction)
                ):
                    sent, marker_pending = marker_pending, None  # taken, whatever comes of it
                    if sent is None:
                        sent = await self.line.send_after_gap(OneFrame(late.marker(address)))
                        assert sent is not None  # the pick always has a frame
                        self.sent(drive, sent.frame)
                    on_wire = sent.frame
                    if transaction.probe:  # what the traffic monitor shows of it
                        transaction.pdu = on_wire[1:-2]
                    marker = await self._catch_up(transaction, sent, drive)
                    if transaction.probe:  # the marker is all a probe asks
                        return self._exchange_answered(transaction, attempt, started, marker, drive)
                    started = time.monotonic()
                    on_wire = frame
                sends += 1
                sending, pending = pending, None
                if sending is not None:  # sent by the pick, counted as it went
                    exchange = await self.line.finish(
                        sending, expect_reply=not broadcast, timeout_s=transaction.timeout_s
                    )
                else:
                    self.sent(drive, frame)
                    exchange = await self.line.transact(
                        frame, expect_reply=not broadcast, timeout_s=transaction.timeout_s
                    )
                if exchange.strays and self.set_aside(exchange.strays):
                    # A frame from the asked drive came before this reply and answered nothing
                    # it owed: this reply may be an older request's. Never handed over.
                    raise BadReply("out_of_step", f"drive {address} sent a frame out of step")
            except ReplyTimeout as exc:
                drive.timeouts += 1
                self._unanswered(address, on_wire, started, exc.strays, transaction.timeout_s)
                dump_frame(self.name, "rx timeout", exc.received)
                errors.append(exc)
                if observers.tap is not None:
                    observers.show(transaction, attempt, started, exc)
                exchange = None  # failed: the next attempt, if any
            except BadReply as exc:
                drive.bad_replies[exc.kind] += 1
                self._unanswered(address, on_wire, started, exc.strays, transaction.timeout_s)
                if cut:  # something came back: not a dead drive's, its retries are due
                    retries, cut = transaction.retries, False
                dump_frame(self.name, f"rx bad {exc.kind}", exc.frame)
                log.debug("bus %s: %s", self.name, exc)
                errors.append(exc)
                if observers.tap is not None:
                    observers.show(transaction, attempt, started, exc)
                exchange = None  # an out-of-step reply too: failed, the next attempt, if any
            except PortError as exc:
                if observers.tap is not None:
                    observers.show(transaction, attempt, started, exc)
                if not broadcast:  # its reply may come to the reopened port
                    late.unanswered(address, on_wire, started, transaction, transaction.timeout_s)
                raise
            finally:
                drive.line_s += time.monotonic() - started
            # Not `continue` in the handlers above: a `continue` inside `try ... finally` is
            # the one construct here that mypyc, which compiles these rooms in a trial
            # (Benchmark page), refuses.
            if exchange is None:
                continue
            return self._exchange_answered(transaction, attempt, started, exchange, drive)
        return self._every_attempt_failed(transaction, drive, errors, sends)

    def _every_attempt_failed(
        self, transaction: Transaction, drive: DriveStats, errors: list[LineError], sends: int
    ) -> Outcome:
        address = transaction.address
        drive.failed += 1
        log.debug("bus %s: drive %d: every attempt failed: %s", self.name, address, errors)
        # A probe that got nothing usable counts as a failure whatever went wrong, so its drive
        # backs off; a request that got bad replies proves its drive is there.
        # A drive heard meanwhile (late replies, set aside) is there too: not a failure.
        if not self._heard_from_carried and (
            transaction.probe or all(isinstance(error, ReplyTimeout) for error in errors)
        ):
            self.failed(address)
        message = f"drive {address} on {self.name}: {errors[-1]}"
        unconfirmed = sends if transaction.pdu and lookup(transaction.pdu[0]).writes else 0
        if unconfirmed and address != BROADCAST_ADDRESS:
            message += (
                f"; the write may have been carried out all the same: it went out {sends} "
                f"time{'s' if sends > 1 else ''} and no reply confirmed it"
            )
            log.warning("bus %s: %s", self.name, message)
        error = GatewayTargetFailed(message)
        error.sent_unconfirmed = unconfirmed
        return error

    async def _catch_up(
        self, transaction: Transaction, sent: Sending, drive: DriveStats
    ) -> Exchange:
        """Read the answer to the marker `sent` (`gateway.bus.late_replies`), the frames before
        it set aside: its drive is in step once it is back. Raises as an attempt does
        (ReplyTimeout when the answer doesn't come in time, BadReply)."""
        address, timeout_s = transaction.address, transaction.timeout_s
        late = self.late_replies
        drive.resyncs += 1
        try:
            exchange = await self.line.finish(
                sent, expect_reply=True, timeout_s=timeout_s, owed=late.owed_frames(address)
            )
        except LineError as exc:
            late.marker_missed(address, sent.frame)
            self.observers.tap_marker(transaction, sent, exc)
            raise  # its line time is the attempt's (`carry`)
        self.observers.tap_marker(transaction, sent, exchange)
        drive.line_s += time.monotonic() - sent.started
        self.set_aside(exchange.strays)
        late.caught_up(address, sent.frame, exchange.reply_pdu or b"")
        self._record(
            drive, exchange.reply_pdu, exchange.gap_s, exchange.busy_s, exchange.reply_heard_at
        )
        return exchange

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
            self.late_replies.unanswered(address, frame, sent_at, self.carrying, timeout_s)
        self.set_aside(strays)

    def set_aside(self, strays: tuple[Stray, ...]) -> bool:
        """Account frames set aside during an attempt (or heard between transactions) in the
        ledger, each for the drive that sent it; True if the drive carried now is left owing
        or unsure by them."""
        late = self.late_replies
        carrying = self.carrying
        asked = carrying.address if carrying is not None else BROADCAST_ADDRESS
        for frame, heard_at in strays:
            address = frame[0]
            dump_frame(self.name, "rx set aside", frame)
            answered = late.heard(frame)
            if address == asked:
                self._heard_from_carried = True
            if answered is None:
                # It answers nothing its drive owed: a reply that contradicts the request, or
                # another address's, counted for the drive asked (as a bad reply always was).
                if asked == BROADCAST_ADDRESS:  # heard between transactions
                    self.drive(address).bad_replies["out_of_step"] += 1
                else:
                    kind = "mismatch" if address == asked else "address"
                    self.drive(asked).bad_replies[kind] += 1
            else:
                self.drive(address).late_replies += 1
                late.seen(address, heard_at, answered)
            if self.health.offline_count and self.health.is_offline(address):
                # It answers again: probe it now, not at the end of its backoff.
                self.health.probe_now(address, time.monotonic())
        if carrying is None or asked not in late.owing:
            return False
        frame = carrying.frame or build_frame(asked, carrying.pdu)
        return late.needs_marker(asked, frame, carrying)

    # -- an attempt's end, either way -------------------------------------------------------------

    def sent(self, drive: DriveStats, frame: bytes, first: Sending | None = None) -> None:
        """An attempt's frame went out (whichever way it ends): counted. `first`: it is the
        transaction's first frame (its request, or a marker before it), sent as the gap ended;
        for a transaction the gap's end found waiting, the silence the gateway added before it
        is observed: beyond the gap, or since the request was queued if that came later (the
        line was idle until then for want of a request, not of the gateway)."""
        drive.transactions += 1
        if FRAMES_CACHED(_DEBUG) is not False:  # the logger's own cache: no call when off
            dump_frame(self.name, "tx", frame)
        if first is not None and self.back_to_back:
            transaction = self.carrying
            assert transaction is not None  # `first` is its frame
            beyond_gap = first.gap_s - self.line_settings.gap_s
            since_queued = first.started - transaction.queued_at
            self.gap_excess.observe(beyond_gap if beyond_gap < since_queued else since_queued)

    def _exchange_answered(
        self,
        transaction: Transaction,
        attempt: int,
        started: float,
        exchange: Exchange,
        drive: DriveStats,
    ) -> Outcome:
        return self.attempt_answered(
            transaction,
            attempt,
            started,
            exchange.reply_pdu,
            exchange.gap_s,
            exchange.busy_s,
            exchange.reply_heard_at,
            drive,
        )

    def attempt_answered(
        self,
        transaction: Transaction,
        attempt: int,
        started: float,
        pdu: bytes | None,
        gap_s: float,
        busy_s: float,
        heard_at: float,
        drive: DriveStats,
    ) -> Outcome:
        """An attempt got its reply `pdu` (or a broadcast went out: None): count it, tell the
        health tracker and the traffic monitor; the waiters get the reply."""
        address = transaction.address
        if pdu is not None and FRAMES_CACHED(_DEBUG) is not False and frame_dump_enabled():
            # The frame as it came: a reply that passed its CRC check rebuilds byte-exact.
            dump_frame(self.name, "rx", build_frame(address, pdu))
        self._record(drive, pdu, gap_s, busy_s, heard_at)
        observers = self.observers
        if observers.tap is not None:
            observers.show(transaction, attempt, started, Exchange(pdu, gap_s, busy_s, heard_at))
        if address == BROADCAST_ADDRESS:
            self.stats.broadcasts += 1
            self.late_replies.broadcast()
        elif address not in self.health.answering:
            self.answered(address)  # back, or its failures to forget
            if not transaction.probe:
                # What a marker may be made from: a request it answered (the first since it
                # last failed is as good as the last, and costs the common case nothing).
                self._answered_frames[address] = transaction.frame or build_frame(
                    address, transaction.pdu
                )
        return pdu

    def _record(
        self, drive: DriveStats, pdu: bytes | None, gap_s: float, busy_s: float, heard_at: float
    ) -> None:
        stats = self.stats
        stats.busy_s += busy_s
        self.reply_heard_at = heard_at
        min_gap_s = stats.min_gap_s
        if min_gap_s is None or gap_s < min_gap_s:
            stats.min_gap_s = gap_s
        if pdu and pdu[0] & 0x80 and len(pdu) > 1:
            drive.exceptions[pdu[1]] += 1

    # -- a drive's health ---------------------------------------------------------------------

    def answered(self, address: int) -> None:
        if self.health.record_answer(address):
            log.warning("bus %s: drive %d is back online", self.name, address)
            self.observers.drive(address, True)

    def failed(self, address: int) -> None:
        if self.health.record_failure(address, time.monotonic()):
            log.warning(
                "bus %s: drive %d offline after %d failed requests; probing it with backoff",
                self.name,
                address,
                self.health.offline_after,
            )
            self.observers.drive(address, False)
