"""Waking before the inter-frame gap ends (`gateway.bus.gap_lead`): the lead is learnt from the
wake-ups, the frame never leaves before the gap has ended, bytes that come while it is chosen
start the gap again with the chosen frame kept, and the lines of one event loop share one spin
budget that decides where their leads settle. Over real ptys."""

from __future__ import annotations

import asyncio
import math
import os
import select
import time
import tty

import pytest

from gateway.bus.gap_lead import (
    BUDGET_WINDOW_S,
    MAX_LEAD_S,
    STEP_BACK_S,
    STEP_BACK_WITHIN_BUDGET_S,
    STEP_S,
    GapLead,
    SpinBudget,
    loop_spin_budget,
)
from gateway.bus.line import Sending, SerialLine
from gateway.bus.queue import Priority
from gateway.config import BusConfig
from gateway.instruments.simulator import SimulatedLine
from gateway.modbus.rtu import build_frame
from gateway.settings import bus_settings
from tests.support import read_pdu, running_bus
from tests.unit.bus.line_users import send_after_gap

STATE_WORD_1 = 0x2100


def test_the_lead_grows_while_wake_ups_are_late_and_never_past_its_bound() -> None:
    lead = GapLead(gap_s=0.032)  # 1200 baud: the bound is MAX_LEAD_S, not a quarter of the gap
    for _ in range(3):
        lead.ready(time.monotonic() - 1e-3)  # the frame was ready after the gap had ended
    assert lead.lead_s == pytest.approx(3 * STEP_S)
    for _ in range(1000):
        lead.ready(time.monotonic() - 1e-3)
    assert lead.lead_s == pytest.approx(MAX_LEAD_S)
    assert lead.spun_s == 0.0  # late: nothing to wait out


def test_an_early_wake_up_waits_out_the_gap_and_shortens_the_lead() -> None:
    lead = GapLead(gap_s=0.0004)  # a short gap: the lead is bound to a quarter of it
    for _ in range(1000):
        lead.ready(time.monotonic() - 1e-3)
    assert lead.lead_s == pytest.approx(0.0001)
    gap_end = time.monotonic() + 0.005  # early even if this test is held up a few milliseconds
    lead.ready(gap_end)
    assert time.monotonic() >= gap_end  # never a frame before the gap's end
    assert lead.spun_s > 0
    assert lead.budget.spun_s == lead.spun_s  # counted against the loop's budget too
    # Nothing spun before it, so within the budget: the small step, towards the 95th percentile
    assert lead.lead_s == pytest.approx(0.0001 - STEP_BACK_WITHIN_BUDGET_S)


def test_past_the_loop_s_spin_budget_the_lead_steps_back_three_times_its_step() -> None:
    """A loop whose lines spun more than its budget in the last window: their leads take the
    big step back (towards the lower quartile); after a window within the budget, the small
    one again. The windows' ends are given, so a loaded machine can't move them."""
    budget = SpinBudget()
    lead = GapLead(gap_s=0.0016, budget=budget)  # 115200 baud: t3.5 is 1.75 ms, near this
    lead.lead_s = 300e-6
    start = time.monotonic()
    budget.spun_s += 0.010  # the loop's lines spun 10 ms in this half second: 2 %
    budget.look(start + BUDGET_WINDOW_S)
    assert not budget.within
    lead.ready(time.monotonic() + 0.005)  # an early wake-up
    assert lead.lead_s == pytest.approx(300e-6 - STEP_BACK_S)
    budget.look(start + 10.0)  # then 9.5 s with only that wake-up's 5 ms spun: 0.05 %
    assert budget.within
    before = lead.lead_s
    lead.ready(time.monotonic() + 0.005)
    assert lead.lead_s == pytest.approx(before - STEP_BACK_WITHIN_BUDGET_S)


@pytest.mark.parametrize(("within", "quantile"), [(True, 0.95), (False, 0.25)])
def test_the_lead_settles_at_the_quantile_of_the_wake_ups_lateness_its_budget_allows(
    within: bool, quantile: float
) -> None:
    """Wake-ups late by 0 to 198 us, evenly: within the budget the lead settles where 95 % of
    them come early (about 190 us), past it where a quarter do (about 50 us)."""
    budget = SpinBudget()
    budget.window_ends = math.inf  # never looked at: the rule under test stays as set
    budget.step_back_s = STEP_BACK_WITHIN_BUDGET_S if within else STEP_BACK_S
    lead = GapLead(gap_s=0.032, budget=budget)  # 1200 baud: bounded by MAX_LEAD_S, not the gap
    lateness = [n * 2e-6 for n in range(100)]
    for _ in range(40):
        for n in range(100):
            late = lateness[(n * 37) % 100]  # every lateness once a round, in a fixed order
            # The timer fired `lead_s` before the gap's end, and the wake-up came `late` after
            # that: the gap ends `lead_s - late` from now.
            lead.ready(time.monotonic() + lead.lead_s - late)
    assert lead.lead_s == pytest.approx(quantile * 200e-6, abs=25e-6)


async def test_the_lines_of_one_event_loop_share_one_spin_budget() -> None:
    """Every line on the loop spins into the same budget: sixteen lines spinning as much as
    one line may would hold up each other's frames sixteen times as long."""
    ends = [os.openpty() for _ in range(2)]
    lines = []
    try:
        for _, slave in ends:
            tty.setraw(slave)
            config = BusConfig.model_validate(
                {"name": f"line{slave}", "port": os.ttyname(slave), "baudrate": 115200}
            )
            line = SerialLine(bus_settings(config).line)
            line.open()
            lines.append(line)
        first, second = lines
        assert first.gap_lead.budget is second.gap_lead.budget
        other_loop = asyncio.new_event_loop()  # another loop's lines don't hold up these
        try:
            assert loop_spin_budget(other_loop) is not first.gap_lead.budget
        finally:
            other_loop.close()
        first.gap_lead.wait_out(time.monotonic() + 0.002)
        second.gap_lead.wait_out(time.monotonic() + 0.003)
        shared = first.gap_lead.budget.spun_s
        assert shared == pytest.approx(first.gap_lead.spun_s + second.gap_lead.spun_s)
        assert shared > 0.004  # the two waits, less the moment before each began to spin
    finally:
        for line in lines:
            line.close()
        for master, slave in ends:
            os.close(master)
            os.close(slave)


@pytest.mark.line(addresses=[1, 2], baudrate=19200, response_delay_ms=0.0)
async def test_back_to_back_transactions_learn_a_lead_and_keep_t35(line: SimulatedLine) -> None:
    """Fast drives, requests always waiting: the line learns to wake before the gap ends, and
    the drives never see a request sooner than t3.5 after the frame before it."""
    async with running_bus(line.path, baudrate=19200) as bus:

        async def client(n: int) -> None:  # a read of its own: none shares a transaction
            for _ in range(60):
                reply = await bus.request(
                    1 + n % 2, read_pdu(0x3000 + n, 2), priority=Priority.READ, client=f"c{n}"
                )
                assert reply is not None
                assert reply[:2] == bytes([3, 4])

        await asyncio.gather(*(client(n) for n in range(4)))
        assert bus.stats.transactions == 240
        assert bus.line.gap_lead.lead_s > 0  # the timer's wake-ups came late: it wakes earlier
        assert bus.gap_excess.counts[0] == 0  # never a gap shorter than t3.5, our side
    assert line.stats["gap_violations"] == 0  # nor the drives'
    assert line.stats["min_gap_s"] >= line.t35_s


async def test_bytes_while_the_frame_is_chosen_start_the_gap_again_with_that_frame() -> None:
    """A byte arrives after the line was last seen quiet, while the next frame is being chosen
    a lead before the gap's end: the frame must not go out t3.5 after the earlier silence, but
    t3.5 after that byte, and it is the frame already chosen (nothing chosen twice, nothing
    lost)."""
    master, slave = os.openpty()
    tty.setraw(slave)
    os.set_blocking(master, False)
    config = BusConfig.model_validate(
        {"name": "line1", "port": os.ttyname(slave), "baudrate": 1200}
    )
    gap_s = bus_settings(config).line.gap_s  # 32 ms at 1200 baud
    frame = build_frame(1, read_pdu(STATE_WORD_1))
    checked = 0
    try:
        for _ in range(10):  # until wake-ups came early enough to choose before the gap's end
            serial = SerialLine(bus_settings(config).line)
            serial.open()  # the line is quiet from here: the first gap ends a gap later
            # Woken well before the gap's end, whatever this machine's wake-ups: an idle VM
            # here wakes a process 250-400 us late, beyond any lead the line would learn.
            serial.gap_lead.lead_s = 0.005
            glitch = Glitch(master, slave, frame, serial.busy_until + gap_s)
            try:
                sending = await asyncio.wait_for(send_after_gap(serial, glitch.pick), 5.0)
            finally:
                serial.close()
            assert await read_exactly(master, len(frame)) == frame  # once, whole
            if glitch.written_at is None:
                continue  # woken after the gap's end: nothing to show, try again
            assert isinstance(sending, Sending)
            assert glitch.picks == 1  # the frame chosen before the byte is the one that went
            assert sending.frame == frame
            assert sending.started - glitch.written_at >= gap_s  # a whole gap after the byte
            checked += 1
            if checked == 3:
                break
    finally:
        os.close(master)
        os.close(slave)
    assert checked >= 1


class Glitch:
    """`Dispatch.pick` for one frame, and a transceiver's glitch byte on the line as it is
    called, if that is before the gap's end."""

    def __init__(self, master: int, slave: int, frame: bytes, gap_end: float) -> None:
        self.master, self.frame, self.gap_end = master, frame, gap_end
        self.arrived = select.poll()
        self.arrived.register(slave, select.POLLIN)
        self.picks = 0
        self.written_at: float | None = None

    def pick(self) -> bytes:
        self.picks += 1
        if self.picks == 1 and time.monotonic() < self.gap_end:
            os.write(self.master, b"\xff")
            self.written_at = time.monotonic()
            # The pty hands the byte over a little later (tens of microseconds, a millisecond
            # on a busy machine): it has arrived by the time the frame is chosen, as a glitch
            # on a wire would have, whatever this machine's pty does.
            assert self.arrived.poll(1000), "the glitch byte never reached the gateway's end"
        return self.frame


async def read_exactly(fd: int, count: int) -> bytes:
    """What the other end of the pty got (the frame), within two seconds."""
    got = bytearray()
    deadline = time.monotonic() + 2.0
    while len(got) < count and time.monotonic() < deadline:
        try:
            got.extend(os.read(fd, 256))
        except BlockingIOError:
            await asyncio.sleep(0.005)
    return bytes(got)
