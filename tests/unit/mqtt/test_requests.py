"""Command payloads read into bus requests (no I/O), the outbox's bounds, the poll plan."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Awaitable, Callable
from datetime import UTC, datetime

import pytest

from gateway.backoff import Backoff
from gateway.config import DriveConfig
from gateway.errors import CommandRefused
from gateway.instruments.embedded_broker import topic_matches
from gateway.mqtt.lanes import Lanes
from gateway.mqtt.outbox import Outbox
from gateway.mqtt.requests import (
    check_age,
    check_waited,
    parse_object,
    parse_read,
    parse_set,
    parse_write,
)
from gateway.poller import PollBlock, poll_schedules
from gateway.profile import get_profile, is_ram_address
from gateway.profile.ram_writes import ram_write_address
from gateway.settings import drive_settings

GD350 = get_profile("gd350")


def reason(call: object) -> str:
    with pytest.raises(CommandRefused) as refused:
        call()  # type: ignore[operator]
    return refused.value.reason


def test_run_with_frequency_is_one_write_of_2000h_2001h() -> None:
    write = parse_set({"command": "run_forward", "frequency_hz": 10.0}, GD350)
    # The INVT manual's own frame: forward run and 10.00 Hz in one 10H write.
    assert write.pdu == bytes.fromhex("10 2000 0002 04 0001 03E8")
    assert write.echo == {"command": "run_forward", "frequency_hz": 10.0}


@pytest.mark.parametrize(
    ("command", "word"),
    [
        ("run_forward", 1),
        ("run_reverse", 2),
        ("jog_forward", 3),
        ("jog_reverse", 4),
        ("stop", 5),
        ("coast_stop", 6),
        ("fault_reset", 7),
        ("jog_stop", 8),
    ],
)
def test_each_command_is_its_control_word(command: str, word: int) -> None:
    assert parse_set({"command": command}, GD350).pdu == bytes((6, 0x20, 0, 0, word))


def test_frequency_alone_writes_the_set_point() -> None:
    assert parse_set({"frequency_hz": 50.12}, GD350).pdu == bytes.fromhex("06 2001 1394")


def test_parameter_scaled_by_the_profile_or_the_message() -> None:
    # P00.11 = 10.0 s travels as 0064H (the manual's example).
    write = parse_write({"parameter": "P00.11", "value": 10.0}, GD350)
    assert write.pdu == bytes.fromhex("06 000B 0064")
    write = parse_write({"parameter": "P05.01", "value": 1.5, "decimals": 2}, GD350)
    assert write.words == (150,)
    write = parse_write({"parameter": "P05.01", "raw": 7}, GD350)
    assert write.words == (7,)


def test_ram_only_goes_to_8xxxh() -> None:
    # Also when the route sends parameter writes to RAM itself: it leaves 8xxxH alone.
    write = parse_write({"parameter": "P00.07", "value": 3, "ram_only": True}, GD350)
    assert write.start == 0x8007
    generic = get_profile("generic")
    assert (
        reason(lambda: parse_write({"parameter": "P00.07", "value": 3, "ram_only": True}, generic))
        == "invalid_request"
    )


@pytest.mark.parametrize(
    ("message", "expected"),
    [
        ({"command": "launch"}, "invalid_request"),
        ({"command": 1}, "invalid_request"),
        ({"frequency_hz": -1}, "invalid_value"),
        ({"frequency_hz": 700.0}, "invalid_value"),
        ({"frequency_hz": True}, "invalid_value"),
        ({"frequency_hz": float("nan")}, "invalid_value"),
        ({"speed": 3}, "invalid_request"),
        ({"parameter": "P00.11"}, "invalid_request"),
        ({"parameter": "P00.11", "value": 1, "raw": 10}, "invalid_request"),
        ({"parameter": "P5.1x", "value": 1}, "invalid_request"),
        ({"parameter": "P12.01", "value": 1}, "invalid_value"),  # in no table: decimals unknown
        ({"parameter": "P00.11", "raw": 70000}, "invalid_value"),
        ({"parameter": "P00.11", "value": 1, "ram_only": "yes"}, "invalid_request"),
        ({"parameter": "2000H", "value": 1, "ram_only": True}, "invalid_request"),
        ({"command": "stop", "parameter": "P00.11", "value": 1}, "invalid_request"),
        ({}, "invalid_request"),
    ],
)
def test_refusals(message: dict[str, object], expected: str) -> None:
    assert reason(lambda: parse_set(message, GD350)) == expected


def test_payload_must_be_a_json_object() -> None:
    assert parse_object(b'{"command": "stop"}') == {"command": "stop"}
    for payload in (b"stop", b"[1]", b"\xff", b""):
        assert reason(lambda p=payload: parse_object(p)) == "invalid_request"


def test_age_of_a_command() -> None:
    now = time.time()
    check_age({}, 10, now)  # no time: nothing to check
    check_age({"time": now - 5}, 10, now)
    check_age({"time": int((now - 5) * 1000)}, 10, now)  # JavaScript's Date.now()
    check_age({"time": datetime.fromtimestamp(now - 5, UTC).isoformat()}, 10, now)
    assert reason(lambda: check_age({"time": now - 11}, 10, now)) == "stale"
    assert reason(lambda: check_age({"time": now + 60}, 10, now)) == "stale"
    assert reason(lambda: check_age({"time": "yesterday"}, 10, now)) == "invalid_request"
    assert reason(lambda: check_age({"time": "2024-05-01T12:00:00"}, 10, now)) == "invalid_request"


def test_read_of_a_signed_register_and_of_a_block() -> None:
    read = parse_read({"register": "3007H"}, 16)
    assert read.result([0xFF9C]) == {"raw": 0xFF9C, "value": -10.0}
    read = parse_read({"parameter": "P07.27", "count": 6}, 16)
    assert read.pdu == bytes.fromhex("03 071B 0006")
    assert read.result([35] * 6)["value"] == [35] * 6
    assert reason(lambda: parse_read({"parameter": "P07.27", "count": 17}, 16)) == "invalid_request"


def test_read_count_is_limited_by_what_the_caller_says_the_drive_takes() -> None:
    # The bridge passes the drive's limit, or Modbus's 125 when the router splits for it.
    assert parse_read({"register": "3000H", "count": 20}, 125).pdu == bytes.fromhex("03 3000 0014")
    assert reason(lambda: parse_read({"register": "3000H", "count": 126}, 125)) == "invalid_request"
    assert reason(lambda: parse_read({"register": "FFFFH", "count": 2}, 125)) == "invalid_request"


@pytest.mark.parametrize(
    ("register", "expected"),
    [
        ("P00.07", 0x8007),
        ("P99.99", 0xE363),
        ("0A01H", 0x8A01),
        ("8007H", 0x8007),  # already the RAM-only address
        ("2000H", None),
        ("2104H", None),  # digits of a parameter (group 33), but a communication register
        ("3020H", None),
        ("5000H", None),
        ("1A2BH", 0x9A2B),  # P26.43, by its hex spelling
        ("0064H", None),  # index 100: no parameter
    ],
)
def test_ram_only_writes_follow_the_profile_rule(register: str, expected: int | None) -> None:
    """One rule for which registers have a RAM-only twin: the profile's, as the router uses it."""
    key = "parameter" if register.startswith("P") else "register"
    message = {key: register, "raw": 1, "ram_only": True}
    if expected is None:
        assert reason(lambda: parse_write(message, GD350)) == "invalid_request"
    else:
        assert parse_write(message, GD350).start == expected
    address = parse_write({key: register, "raw": 1}, GD350).start
    twin = ram_write_address(address)
    assert (twin if is_ram_address(twin) else None) == expected


def test_time_waited_in_the_gateway() -> None:
    check_waited(100.0, 10, 105.0)
    assert reason(lambda: check_waited(100.0, 10, 111.0)) == "stale"


def test_outbox_takes_back_what_was_not_sent_unless_newer_came() -> None:
    outbox = Outbox()
    outbox.put_state("pump1", {"state": "fault"})
    outbox.put_availability("pump1", True)
    pending = outbox.take()
    outbox.put_state("pump1", {"state": "stopped"})
    outbox.restore(pending)  # the connection broke before any of it went out
    again = outbox.take()
    assert again.states == {"pump1": {"state": "stopped"}}  # the newer state wins
    assert again.availability == {"pump1": True}


async def test_lanes_keep_order_within_a_lane_and_run_lanes_side_by_side() -> None:
    lanes = Lanes(max_waiting=2)
    release = asyncio.Event()
    done: list[str] = []

    def job(name: str, wait: bool = False) -> Callable[[], Awaitable[None]]:
        async def run() -> None:
            if wait:
                await release.wait()
            done.append(name)

        return run

    assert lanes.submit("pump1", job("pump1 get", wait=True))
    await asyncio.sleep(0)  # its task takes it: running, no longer waiting
    assert lanes.submit("pump1", job("pump1 stop"))
    assert lanes.submit("pump1", job("pump1 run"))
    assert not lanes.submit("pump1", job("pump1 one too many"))  # two already wait
    assert lanes.submit("fan2", job("fan2 stop"))
    for _ in range(10):
        await asyncio.sleep(0)  # turns of the event loop, not time: the lanes' tasks step
    assert done == ["fan2 stop"]  # not behind pump1's
    release.set()
    for _ in range(10):
        await asyncio.sleep(0)  # turns of the event loop, not time
    assert done == ["fan2 stop", "pump1 get", "pump1 stop", "pump1 run"]
    assert lanes.running == 0
    assert lanes.submit("pump1", job("pump1 later"))  # a new worker for a lane gone idle
    await lanes.close(1.0)
    assert done[-1] == "pump1 later" or lanes.dropped == 1


async def test_lanes_close_cancels_running_and_drops_waiting_jobs() -> None:
    lanes = Lanes(max_waiting=4)
    started = asyncio.Event()
    cancelled: list[bool] = []

    async def stuck() -> None:
        started.set()
        try:
            await asyncio.Event().wait()
        except asyncio.CancelledError:
            cancelled.append(True)
            raise

    async def never() -> None:
        raise AssertionError("a job waiting at close must not run")

    lanes.submit("pump1", stuck)
    lanes.submit("pump1", never)
    await started.wait()
    await lanes.close(1.0)
    assert cancelled == [True]
    assert lanes.dropped == 1
    assert lanes.running == 0


def test_outbox_keeps_the_newest_state() -> None:
    outbox = Outbox()
    outbox.put_state("pump1", {"state": "stopped"})
    outbox.put_state("pump1", {"state": "running_forward"})
    pending = outbox.take()
    assert pending.states == {"pump1": {"state": "running_forward"}}
    assert outbox.stats.states_superseded == 1
    assert not outbox.take()


def test_poll_groups_are_cut_into_16_word_blocks() -> None:
    drive = DriveConfig.model_validate(
        {
            "name": "pump1",
            "bus": "line1",
            "address": 1,
            "model": "gd350",
            "poll": [{"name": "all", "start": 0x3000, "count": 22, "interval_ms": 1000}],
        }
    )
    (schedule,) = poll_schedules(drive_settings(drive))
    assert schedule.blocks == (PollBlock(0x3000, 16), PollBlock(0x3010, 6))
    assert schedule.interval_s == 1.0
    default = DriveConfig.model_validate({"name": "fan", "bus": "line1", "address": 2})
    groups = {s.group: s for s in poll_schedules(drive_settings(default))}
    assert groups["state"].blocks == (PollBlock(0x2100, 3),)
    assert groups["state"].interval_s == 0.5
    assert groups["running"].blocks == (PollBlock(0x3000, 12),)


def test_backoff_doubles_to_its_cap_with_jitter() -> None:
    backoff = Backoff(0.5, 4.0)
    delays = [backoff.next_delay() for _ in range(6)]
    assert 0.25 <= delays[0] <= 0.5
    assert all(d <= 4.0 for d in delays)
    assert delays[-1] >= 2.0
    backoff.reset()
    assert backoff.next_delay() <= 0.5


@pytest.mark.parametrize(
    ("topic_filter", "topic", "matches"),
    [
        ("invt/#", "invt/pump1", True),
        ("invt/#", "invt", True),
        ("invt/+/set", "invt/pump1/set", True),
        ("invt/+/set", "invt/pump1/set/response", False),
        ("invt/pump1", "invt/pump1/availability", False),
        ("#", "$SYS/broker", False),
    ],
)
def test_embedded_broker_wildcards(topic_filter: str, topic: str, matches: bool) -> None:
    assert topic_matches(topic_filter, topic) is matches
