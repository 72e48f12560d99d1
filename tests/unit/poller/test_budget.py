"""The polls' share of a line, counted by hand from the frames' sizes."""

from __future__ import annotations

import pytest

from gateway.modbus.timing import CharacterFormat
from gateway.poller.budget import block_time_s, poll_load
from gateway.poller.plan import PollBlock, PollSchedule
from gateway.profile.point_types import Table

LINE = CharacterFormat(9600, "E")  # 11 bits a character: 1.1458 ms; t3.5 = 4.01 ms
CHARACTER_S = 11 / 9600


def test_a_read_is_its_request_its_reply_and_two_silences() -> None:
    # 03H of 2 registers: request 8 bytes, reply 1+1+1+4+2 = 9 bytes: 17 characters.
    assert block_time_s(PollBlock(0, 2), LINE) == pytest.approx(
        17 * 11 / 9600 + 2 * 3.5 * 11 / 9600
    )
    # 01H of 9 coils: 2 data bytes.
    assert block_time_s(PollBlock(0, 9, Table.COIL), LINE) == pytest.approx(
        15 * 11 / 9600 + 7 * 11 / 9600
    )


def test_the_load_adds_every_schedule_per_second() -> None:
    fast = PollSchedule("fast", 0.5, (PollBlock(0, 2), PollBlock(10, 2)))
    slow = PollSchedule("slow", 10.0, (PollBlock(0, 2, Table.INPUT),))
    load = poll_load([fast, slow], LINE)
    assert load.requests_per_s == pytest.approx(4.1)
    assert load.busy_fraction == pytest.approx(4.1 * 24 * CHARACTER_S)
