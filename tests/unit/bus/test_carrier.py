"""One transaction carried through its attempts (`Carrier`), seen as a user sees it: through a real
bus on simulated drives over a pty, by its answer, the counters metrics read (transactions,
retries, timeouts, bad replies, late replies, resyncs, line time), the traffic monitor's tap and
the request observers' `RequestDone` records, each told once per request however many attempts
it took."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable

import pytest

from gateway.bus import Bus
from gateway.bus.bus import RequestDone
from gateway.bus.line import Exchange
from gateway.bus.queue import Priority, Transaction
from gateway.errors import GatewayTargetFailed, LineError
from gateway.instruments.simulator import SimulatedLine
from tests.support import eventually, read_pdu, running_bus, write_pdu

STATE_WORD_1 = 0x2100
FREQUENCY_SETPOINT = 0x2001
STOPPED_REPLY = bytes.fromhex("03 02 00 03")
SILENT = 9
"""An address nobody answers on."""
GATEWAY_TARGET_FAILED = 0x0B

pytestmark = pytest.mark.line(addresses=[1, 2])

Seen = list[tuple[str, int, bool]]
"""What the traffic monitor's tap was shown: (client, attempt, answered) per attempt."""


def watch(bus: Bus) -> tuple[list[RequestDone], Seen]:
    """The request observers' records and the tap's attempts, from now."""
    done: list[RequestDone] = []
    seen: Seen = []
    bus.add_request_observer(lambda *fields: done.append(RequestDone(*fields)))

    def tap(
        _bus: str, transaction: Transaction, attempt: int, _at: float, outcome: Exchange | LineError
    ) -> None:
        seen.append((transaction.client, attempt, isinstance(outcome, Exchange)))

    bus.tap = tap
    return done, seen


async def read(bus: Bus, address: int, timeout_s: float | None = None) -> bytes | None:
    return await bus.request(
        address, read_pdu(STATE_WORD_1), priority=Priority.READ, client="t", timeout_s=timeout_s
    )


def after_the_first_attempt(bus: Bus, mend: Callable[[], None]) -> None:
    """`mend` the line as the first attempt ends (from the tap, which hears of each attempt
    before the next is made): the retry finds it sound."""
    watching = bus.tap
    assert watching is not None

    def tap(
        name: str, transaction: Transaction, attempt: int, at: float, outcome: Exchange | LineError
    ) -> None:
        watching(name, transaction, attempt, at, outcome)
        if attempt == 0 and not isinstance(outcome, Exchange):
            mend()

    bus.tap = tap


async def test_a_request_whose_first_reply_is_lost_is_answered_by_its_retry(
    line: SimulatedLine,
) -> None:
    line.set_line_faults(rate=1.0, kinds=["silence"])  # the drive hears, its reply is lost
    async with running_bus(line.path, timeout_ms=100, retries=2, offline_after=1) as bus:
        done, seen = watch(bus)
        after_the_first_attempt(bus, lambda: line.set_line_faults(rate=0.0))
        started = time.monotonic()
        assert await read(bus, 1) == STOPPED_REPLY
        took_s = time.monotonic() - started
        drive = bus.drive_stats[1]
        assert (drive.transactions, drive.retries, drive.timeouts, drive.failed) == (2, 1, 1, 0)
        assert (bus.stats.transactions, bus.stats.retries, bus.stats.timeouts) == (2, 1, 1)
        assert drive.line_s >= 0.1  # the timeout's line time is the drive's
        assert not bus.health.is_offline(1)  # answered in the end: offline_after 1 not reached
    assert seen == [("t", 0, False), ("t", 1, True)]
    # Told once, for the request (not per attempt), timed over both attempts.
    assert [(d.address, d.client, d.code) for d in done] == [(1, "t", None)]
    assert took_s >= done[0].duration_s >= 0.1


async def test_a_corrupt_reply_is_counted_by_kind_and_retried(line: SimulatedLine) -> None:
    line.set_line_faults(rate=1.0, kinds=["crc"])
    async with running_bus(line.path, timeout_ms=200, retries=2) as bus:
        done, seen = watch(bus)
        after_the_first_attempt(bus, lambda: line.set_line_faults(rate=0.0))
        assert await read(bus, 1) == STOPPED_REPLY
        drive = bus.drive_stats[1]
        assert drive.bad_replies == {"crc": 1}
        assert bus.stats.bad_replies == {"crc": 1}
        assert (drive.transactions, drive.retries, drive.timeouts) == (2, 1, 0)
    assert seen == [("t", 0, False), ("t", 1, True)]
    assert [d.code for d in done] == [None]


async def test_bad_replies_on_every_attempt_fail_the_request_but_never_the_drive(
    line: SimulatedLine,
) -> None:
    """A drive that answers, however badly, is there: it is never taken offline for it."""
    line.set_line_faults(rate=1.0, kinds=["crc"])
    heard: list[tuple[int, bool]] = []
    async with running_bus(line.path, timeout_ms=200, retries=2, offline_after=1) as bus:
        done, _ = watch(bus)
        bus.add_listener(lambda _bus, address, online: heard.append((address, online)))
        with pytest.raises(GatewayTargetFailed):
            await read(bus, 1)
        drive = bus.drive_stats[1]
        assert drive.bad_replies == {"crc": 3}
        assert (drive.transactions, drive.retries, drive.failed) == (3, 2, 1)
        assert not bus.health.is_offline(1)
        line.set_line_faults(rate=0.0)
        assert await read(bus, 1) == STOPPED_REPLY
    assert heard == []
    assert [d.code for d in done] == [GATEWAY_TARGET_FAILED, None]


async def test_a_write_no_reply_confirmed_says_how_often_it_went_out(line: SimulatedLine) -> None:
    async with running_bus(line.path, timeout_ms=50, retries=1, offline_after=5) as bus:
        with pytest.raises(GatewayTargetFailed) as failed:
            await bus.request(
                SILENT, write_pdu(FREQUENCY_SETPOINT, 2500), priority=Priority.WRITE, client="t"
            )
        assert failed.value.sent_unconfirmed == 2
        assert "it went out 2 times and no reply confirmed it" in str(failed.value)
        drive = bus.drive_stats[SILENT]
        assert (drive.transactions, drive.retries, drive.timeouts, drive.failed) == (2, 1, 2, 1)
        # A read that fails so is no write: nothing may have been carried out.
        with pytest.raises(GatewayTargetFailed) as read_failed:
            await read(bus, SILENT)
        assert read_failed.value.sent_unconfirmed == 0


async def late_then_in_step(line: SimulatedLine, bus: Bus) -> bytes | None:
    """Drive 1 answers a read 250 ms late, past its 50 ms timeout and the drain after it; then
    a read of another register (so its reply can't be mistaken for the late one), with a
    timeout that lets the marker's answer come behind the late reply: that read's reply."""
    line.set_reply_delay(1, 250)
    with pytest.raises(GatewayTargetFailed):
        await read(bus, 1, timeout_s=0.05)
    line.set_reply_delay(1, 0)
    return await bus.request(
        1, read_pdu(FREQUENCY_SETPOINT), priority=Priority.READ, client="t", timeout_s=1.0
    )


async def test_a_drive_that_owes_a_reply_gets_a_marker_first_and_its_late_reply_is_set_aside(
    line: SimulatedLine,
) -> None:
    """The drive owes the late reply, so the next request to it is preceded by a marker (a
    resync), the late reply is set aside when it comes (a late reply, never the next
    request's answer), and the request is answered in step."""
    async with running_bus(line.path, retries=0, offline_after=5) as bus:
        done, seen = watch(bus)
        reply = await late_then_in_step(line, bus)
        assert reply == bytes.fromhex("03 02 00 00")  # the setpoint, never state word 1's 3
        drive = bus.drive_stats[1]
        assert (drive.timeouts, drive.late_replies, drive.resyncs) == (1, 1, 1)
        assert (bus.stats.late_replies, bus.stats.resyncs) == (1, 1)
        assert drive.transactions == 3  # the request, the marker, the request
        assert drive.bad_replies == {}
        assert drive.line_s > 0.05
    assert seen == [("t", 0, False), ("resync", 0, True), ("t", 0, True)]
    assert [d.code for d in done] == [GATEWAY_TARGET_FAILED, None]


async def test_the_late_reply_hint_names_the_timeout_its_request_had(
    line: SimulatedLine, caplog: pytest.LogCaptureFixture
) -> None:
    async with running_bus(line.path, retries=0, offline_after=5) as bus:
        assert await late_then_in_step(line, bus) == bytes.fromhex("03 02 00 00")
    hints = [r.getMessage() for r in caplog.records if "later than timeout_ms" in r.getMessage()]
    assert len(hints) == 1
    assert "later than timeout_ms (50)" in hints[0]


async def test_an_offline_drive_is_probed_and_back_once_it_answers(line: SimulatedLine) -> None:
    heard: list[tuple[int, bool]] = []
    line.set_dead(1)
    async with running_bus(line.path, timeout_ms=50, retries=0, offline_after=1) as bus:
        bus.health.probe_initial_s = 0.05  # the first probe soon, not after a second
        bus.add_listener(lambda _bus, address, online: heard.append((address, online)))
        _, seen = watch(bus)
        with pytest.raises(GatewayTargetFailed):
            await read(bus, 1)
        assert heard == [(1, False)]
        line.set_dead(1, False)
        await eventually(lambda: heard == [(1, False), (1, True)], within_s=3.0, what="back")
        assert await read(bus, 1) == STOPPED_REPLY
        drive = bus.drive_stats[1]
        assert drive.resyncs >= 1  # the probe is a marker, and its answer counts as one
        assert drive.failed >= 1
    # The request that failed, probes until one was answered, the read.
    assert seen[0] == ("t", 0, False)
    assert seen[-2:] == [("probe", 0, True), ("t", 0, True)]
    assert {client for client, _, _ in seen[1:-1]} == {"probe"}


async def test_a_broadcast_is_carried_without_a_reply_and_observed_as_answered(
    line: SimulatedLine,
) -> None:
    async with running_bus(line.path, turnaround_ms=50) as bus:
        done, seen = watch(bus)
        started = time.monotonic()
        broadcast = bus.request(
            0, write_pdu(FREQUENCY_SETPOINT, 2500), priority=Priority.WRITE, client="t"
        )
        after = read(bus, 1)
        assert list(await asyncio.gather(broadcast, after)) == [None, STOPPED_REPLY]
        took_s = time.monotonic() - started
        assert bus.stats.broadcasts == 1
        assert bus.drive_stats[0].transactions == 1
        assert (bus.stats.timeouts, bus.stats.retries, bus.stats.failed) == (0, 0, 0)
        assert bus.drive_stats[0].line_s > 0
    assert took_s >= 0.05  # the read waited out the drives' turnaround after the broadcast
    assert seen == [("t", 0, True), ("t", 0, True)]
    assert [(d.address, d.code) for d in done] == [(0, None), (1, None)]
    assert line.stats["broadcasts"] == 1


async def test_a_drives_exception_is_its_answer_counted_by_code(line: SimulatedLine) -> None:
    async with running_bus(line.path, retries=2) as bus:
        done, _ = watch(bus)
        reply = await bus.request(1, read_pdu(0xFFFF), priority=Priority.READ, client="t")
        assert reply is not None
        assert reply[0] == 0x83
        code = reply[1]
        assert bus.drive_stats[1].exceptions == {code: 1}
        assert bus.stats.exceptions == {code: 1}
        assert (bus.stats.transactions, bus.stats.retries, bus.stats.failed) == (1, 0, 0)
    assert [d.code for d in done] == [code]
