"""Who is told what a bus does (`BusObservers`), and how a transaction's waiters are answered
(`give`, `Observed`): each waiter still waiting gets the outcome and is reported once,
timed from its own request; a waiter gone gets nothing; an observer or listener that raises
costs nothing else."""

from __future__ import annotations

import asyncio
import logging
import time

import pytest

from gateway.bus.exchange import Exchange, Sending
from gateway.bus.observers import RESYNC_CLIENT, BusObservers, Observed, give
from gateway.bus.queue import Priority, Transaction, Waiter
from gateway.bus.stats import RequestDone
from gateway.errors import BusClosed, GatewayTargetFailed, LineError
from gateway.modbus.rtu import build_frame
from tests.support import read_pdu

STATE_WORD_1 = 0x2100
READ = read_pdu(STATE_WORD_1)
STOPPED_REPLY = bytes.fromhex("03 02 00 03")


def observers_with_records() -> tuple[BusObservers, list[RequestDone]]:
    observers = BusObservers("line1")
    done: list[RequestDone] = []
    observers.request_observers.append(lambda *fields: done.append(RequestDone(*fields)))
    return observers, done


def transaction(
    waiters: list[Waiter], observed_by: BusObservers | None, queued_at: float, probe: bool = False
) -> Transaction:
    return Transaction(
        1, READ, Priority.READ, "own", 1.0, 0, True, waiters, probe, b"", queued_at, observed_by
    )


def waiter() -> asyncio.Future[bytes | None]:
    return asyncio.get_running_loop().create_future()


async def test_every_waiter_still_waiting_gets_the_reply_each_reported_from_its_own_start() -> None:
    observers, done = observers_with_records()
    now = time.monotonic()
    own, gone, joined, joined_gone = waiter(), waiter(), waiter(), waiter()
    gone.cancel()  # its client went while it waited
    joined_gone.cancel()
    # Ones that joined the queued transaction later (identical reads), reported by a wrapper.
    observed = Observed(observers, joined, 1, READ, "joined", now - 1.0)
    observed_gone = Observed(observers, joined_gone, 1, READ, "joined-gone", now - 1.0)
    give(transaction([own, gone, observed, observed_gone], observers, now - 5.0), STOPPED_REPLY)
    assert own.result() == STOPPED_REPLY
    assert joined.result() == STOPPED_REPLY
    assert gone.cancelled()
    assert joined_gone.cancelled()
    assert [(d.bus, d.address, d.function, d.client, d.code) for d in done] == [
        ("line1", 1, 0x03, "own", None),
        ("line1", 1, 0x03, "joined", None),
    ]
    assert 5.0 <= done[0].duration_s < 6.0  # from the transaction's queueing
    assert 1.0 <= done[1].duration_s < 2.0  # from its own request, not the transaction's


async def test_a_waiter_gone_is_not_reported_nor_is_one_that_nobody_observes() -> None:
    observers, done = observers_with_records()
    own = waiter()
    own.cancel()
    give(transaction([own], observers, time.monotonic()), STOPPED_REPLY)
    unobserved = waiter()
    give(transaction([unobserved], None, time.monotonic()), STOPPED_REPLY)
    assert unobserved.result() == STOPPED_REPLY
    assert done == []


async def test_a_failure_reaches_every_waiter_with_its_exception_code() -> None:
    observers, done = observers_with_records()
    own, joined = waiter(), waiter()
    observed = Observed(observers, joined, 1, READ, "joined", time.monotonic())
    error = GatewayTargetFailed("drive 1 on line1: no reply")
    give(transaction([own, observed], observers, time.monotonic()), error)
    assert own.exception() is error
    assert joined.exception() is error
    assert [(d.client, d.code) for d in done] == [("own", 0x0B), ("joined", 0x0B)]
    # A closing bus's answer is a gateway failure too, as the caller sees it.
    closed = waiter()
    give(transaction([closed], observers, time.monotonic()), BusClosed("bus line1 closed"))
    assert isinstance(closed.exception(), BusClosed)
    assert done[-1].code == 0x0B


async def test_a_drives_exception_reply_is_reported_with_its_code() -> None:
    observers, done = observers_with_records()
    own = waiter()
    refusal = bytes.fromhex("83 02")  # illegal data address
    give(transaction([own], observers, time.monotonic()), refusal)
    assert own.result() == refusal
    assert [(d.function, d.code) for d in done] == [(0x03, 0x02)]
    # A broadcast's answer (None) and an empty PDU: reported, no code, function 0.
    observers.report(0, b"", "t", time.monotonic(), None)
    assert (done[-1].address, done[-1].function, done[-1].code) == (0, 0, None)


async def test_an_observer_that_raises_stops_neither_the_others_nor_the_answer(
    caplog: pytest.LogCaptureFixture,
) -> None:
    observers = BusObservers("line1")
    told: list[str] = []

    def broken(*_fields: object) -> None:
        raise RuntimeError("a bug in an observer")

    observers.request_observers[:] = [broken, lambda *fields: told.append(str(fields[3]))]
    own = waiter()
    with caplog.at_level(logging.ERROR, logger="gateway.bus.bus"):
        give(transaction([own], observers, time.monotonic()), STOPPED_REPLY)
    assert own.result() == STOPPED_REPLY
    assert told == ["own"]
    assert "request observer failed" in caplog.text


def test_a_drive_or_port_listener_that_raises_stops_none_of_the_others(
    caplog: pytest.LogCaptureFixture,
) -> None:
    observers = BusObservers("line1")
    drives: list[tuple[str, int, bool]] = []
    ports: list[tuple[str, str, bool, str]] = []

    def broken(*_args: object) -> None:
        raise RuntimeError("a bug in a listener")

    observers.drive_listeners[:] = [broken, lambda *args: drives.append(args)]
    observers.port_listeners[:] = [broken, lambda *args: ports.append(args)]
    observers.drive(3, False)
    observers.port("/dev/ttyUSB0", True, "unplugged")
    assert drives == [("line1", 3, False)]
    assert ports == [("line1", "/dev/ttyUSB0", True, "unplugged")]
    assert "drive listener failed" in caplog.text
    assert "port listener failed" in caplog.text


def test_a_marker_is_shown_to_the_traffic_monitor_as_its_own_request_but_a_probe_is_not() -> None:
    observers = BusObservers("line1")
    shown: list[tuple[str, Transaction, int, float, Exchange | LineError]] = []
    marker = build_frame(1, bytes.fromhex("08 0000 1234"))
    sent = Sending(marker, 12.5, 0.002, len(marker))
    outcome = Exchange(bytes.fromhex("08 0000 1234"), 0.002, 0.01)
    request = transaction([], None, 0.0)
    observers.tap_marker(request, sent, outcome)  # nobody watching: nothing to do
    observers.tap = lambda *args: shown.append(args)
    observers.tap_marker(request, sent, outcome)
    observers.tap_marker(transaction([], None, 0.0, probe=True), sent, outcome)
    ((bus, shown_as, attempt, started, result),) = shown
    assert (bus, shown_as.address, shown_as.client, shown_as.pdu) == (
        "line1",
        1,
        RESYNC_CLIENT,
        bytes.fromhex("08 0000 1234"),
    )
    assert (attempt, started, result) == (0, 12.5, outcome)


def test_a_reopened_bus_takes_over_its_listeners_as_copies() -> None:
    old = BusObservers("line1")
    old.drive_listeners.append(lambda *_args: None)
    old.request_observers.append(lambda *_fields: None)
    old.tap = lambda *_args: None
    new = BusObservers("line1")
    new.take(old)
    assert new.drive_listeners == old.drive_listeners
    assert new.request_observers == old.request_observers
    assert new.tap is old.tap
    new.request_observers.clear()  # one removed from the new bus stays on the old one's list
    assert len(old.request_observers) == 1
