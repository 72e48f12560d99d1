"""Who is told what a bus does: drive listeners (offline, back), port listeners (lost, open
again), request observers (a caller's request answered: metrics, the console) and the traffic
monitor's tap (every attempt on the wire); and the one way a transaction's waiters are answered,
each observed waiter reported to the request observers as it is (`give`)."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import TYPE_CHECKING

from gateway.bus.queue import Priority, Transaction
from gateway.errors import GatewayError, ModbusError

if TYPE_CHECKING:
    from gateway.bus.exchange import Exchange, Sending
    from gateway.bus.queue import Waiter
    from gateway.errors import LineError

log = logging.getLogger("gateway.bus.bus")

RESYNC_CLIENT = "resync"
"""The traffic monitor's client of a marker sent before a request (`gateway.bus.late_replies`)."""

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
Tap = Callable[[str, "Transaction", int, float, "Exchange | LineError"], None]
"""Told of every attempt on the wire while set (the console's traffic monitor): bus name, the
transaction, the attempt (0: first), when it started (monotonic) and what came of it."""


class BusObservers:
    """One bus's listeners, observers and tap. A listener or observer that fails is logged and
    costs nothing else: the line goes on."""

    __slots__ = ("drive_listeners", "name", "port_listeners", "request_observers", "tap")

    def __init__(self, name: str) -> None:
        self.name = name
        self.drive_listeners: list[DriveListener] = []
        self.port_listeners: list[PortListener] = []
        self.request_observers: list[RequestObserver] = []
        self.tap: Tap | None = None
        """None unless someone watches the traffic: then one attribute test per attempt."""

    def take(self, old: BusObservers) -> None:
        """A reload reopened `old`'s line: whoever listened to it listens here."""
        self.drive_listeners = list(old.drive_listeners)
        self.port_listeners = list(old.port_listeners)
        self.request_observers = list(old.request_observers)
        self.tap = old.tap

    def report(
        self,
        address: int,
        pdu: bytes,
        client: str,
        started: float,
        reply: bytes | None,
        code: int | None = None,
    ) -> None:
        """A caller's request to `address` is answered: with `reply` (None: a broadcast's, or
        none), or refused or failed with `code`; a reply's exception code is worked out here."""
        if reply is not None and len(reply) > 1 and reply[0] & 0x80:
            code = reply[1]
        function, duration_s = pdu[0] if pdu else 0, time.monotonic() - started
        for observer in self.request_observers:
            try:
                observer(self.name, address, function, client, duration_s, code)
            except Exception:
                log.exception("bus %s: request observer failed", self.name)

    def show(
        self,
        transaction: Transaction,
        attempt: int,
        started: float,
        outcome: Exchange | LineError,
    ) -> None:
        """Tell the tap (set: the caller looked) of an attempt. A tap that fails is logged and
        costs nothing else: the traffic monitor's trouble must not cost the request its
        answer."""
        tap = self.tap
        if tap is None:
            return
        try:
            tap(self.name, transaction, attempt, started, outcome)
        except Exception:
            log.exception("bus %s: the traffic monitor's tap failed", self.name)

    def tap_marker(
        self, transaction: Transaction, sent: Sending, outcome: Exchange | LineError
    ) -> None:
        """Show the traffic monitor a marker as what it is: its own request, client `resync`,
        before the request it brought its drive in step for. A probe is its marker (its
        attempt is shown as the probe's, with the marker's request: `Dispatch.pick`)."""
        tap = self.tap
        if tap is not None and not transaction.probe:
            marker = Transaction(
                transaction.address,
                sent.frame[1:-2],
                Priority.READ,
                RESYNC_CLIENT,
                transaction.timeout_s,
                0,
            )
            self.show(marker, 0, sent.started, outcome)

    def drive(self, address: int, online: bool) -> None:
        for listener in self.drive_listeners:
            try:
                listener(self.name, address, online)
            except Exception:
                log.exception("bus %s: drive listener failed", self.name)

    def port(self, port: str, lost: bool, reason: str) -> None:
        for listener in self.port_listeners:
            try:
                listener(self.name, port, lost, reason)
            except Exception:
                log.exception("bus %s: port listener failed", self.name)


class Observed:
    """A waiter that joined a transaction already queued (an identical read), whose outcome the
    request observers are told of, timed from its own request. (A transaction's own waiter is
    reported through `Transaction.observed_by`: no wrapper for the common case.)"""

    __slots__ = ("_address", "_client", "_observers", "_pdu", "_started", "_waiter", "done")

    def __init__(
        self,
        observers: BusObservers,
        waiter: Waiter,
        address: int,
        pdu: bytes,
        client: str,
        started: float,
    ) -> None:
        self._observers = observers
        self._waiter = waiter
        self.done = waiter.done
        """The waiter's own: asked once or twice per request, without a call of ours between."""
        self._address = address
        self._pdu = pdu
        self._client = client
        self._started = started

    def set_result(self, result: bytes | None, /) -> None:
        self._observers.report(self._address, self._pdu, self._client, self._started, result)
        self._waiter.set_result(result)

    def set_exception(self, exception: BaseException, /) -> None:
        self._report(exception.code if isinstance(exception, ModbusError) else None)
        self._waiter.set_exception(exception)

    def _report(self, code: int | None) -> None:
        self._observers.report(self._address, self._pdu, self._client, self._started, None, code)


Outcome = bytes | GatewayError | None
"""What a carried transaction's waiters get: its reply's PDU (None: a broadcast's, which has
none), or the error that ended it."""


def give(transaction: Transaction, outcome: Outcome) -> None:
    """Give every waiter still waiting the transaction's `outcome`: the reply, or the error
    raised in it. The transaction's own waiter is reported to the request observers first
    (`Transaction.observed_by`), with the exception code of a drive's exception reply or of a
    Modbus error."""
    observers = transaction.observed_by  # for its own waiter, the first
    if isinstance(outcome, GatewayError):
        error: GatewayError | None = outcome
        reply, code = None, outcome.code if isinstance(outcome, ModbusError) else None
    else:
        error, reply, code = None, outcome, None
    for waiter in transaction.waiters:
        if not waiter.done():
            if observers is not None:
                observers.report(
                    transaction.address,
                    transaction.pdu,
                    transaction.client,
                    transaction.queued_at,
                    reply,
                    code,
                )
            if error is None:
                waiter.set_result(reply)
            else:
                waiter.set_exception(error)
        observers = None
