"""What the poller makes of a drive's polls, as pure logic: the events a dashboard hears about
(lost, back, fault raised, fault cleared), each once, and the 16-word blocks a poll group is read
in.

Kept to the functions that take a drive profile, not a configuration model (the poller's
constructor and `poll_schedules` take the configuration; the MQTT tests cover them end to end)."""

from __future__ import annotations

from gateway.poller.drive_state import DriveState, EventKind, iso_time
from gateway.poller.plan import PollBlock, blocks
from gateway.profile import get_profile

STATE_WORDS = 0x2100
"""State word 1, state word 2, fault code (2100H-2102H): the first poll group of an INVT drive."""
STOPPED, FAULT = 3, 4
CE = 18
"""RS-485 communication fault, as the manual's fault table numbers it."""
OL1 = 11


def polled(state: DriveState, state_word: int, fault: int, at: float = 1000.0) -> list[EventKind]:
    return [event.kind for event in state.record_poll(STATE_WORDS, [state_word, 0, fault], at)]


def test_a_configured_drive_never_seen_is_reported_offline_once() -> None:
    state = DriveState("pump1", get_profile("gd350"))
    assert [e.kind for e in state.set_online(False)] == [EventKind.DRIVE_OFFLINE]
    assert state.set_online(False) == []  # still silent: no news


def test_the_first_answer_is_no_news_and_a_drive_coming_back_is() -> None:
    state = DriveState("pump1", get_profile("gd350"))
    assert polled(state, STOPPED, 0) == []
    assert state.online is True
    assert [e.kind for e in state.set_online(False)] == [EventKind.DRIVE_OFFLINE]
    assert polled(state, STOPPED, 0) == [EventKind.DRIVE_ONLINE]


def test_a_fault_is_raised_with_its_name_and_a_snapshot_and_cleared_once() -> None:
    state = DriveState("pump1", get_profile("gd350"))
    polled(state, STOPPED, 0)
    events = state.record_poll(STATE_WORDS, [FAULT, 0, CE], 1001.0)
    (raised,) = events
    assert raised.kind is EventKind.FAULT_RAISED
    assert raised.drive == "pump1"
    assert raised.data["fault_code"] == CE
    assert raised.data["fault_name"] == "CE"
    assert raised.snapshot["fault_code"] == CE  # the telemetry of the very poll that saw it
    assert polled(state, FAULT, CE) == []  # the same fault polled again: no second event
    assert polled(state, STOPPED, 0) == [EventKind.FAULT_CLEARED]
    assert polled(state, STOPPED, 0) == []


def test_one_fault_replaced_by_another_clears_the_first_then_raises_the_second() -> None:
    state = DriveState("pump1", get_profile("gd350"))
    polled(state, FAULT, CE)
    events = state.record_poll(STATE_WORDS, [FAULT, 0, OL1], 1002.0)
    assert [(e.kind, e.data["fault_code"]) for e in events] == [
        (EventKind.FAULT_CLEARED, CE),
        (EventKind.FAULT_RAISED, OL1),
    ]


def test_a_generic_device_shows_its_words_under_their_addresses() -> None:
    state = DriveState("meter", get_profile("generic"))
    state.record_poll(0x0010, [7, 8], at=0.25)
    assert state.telemetry() == {
        "register_0010h": 7,
        "register_0011h": 8,
        "last_seen": "1970-01-01T00:00:00.250Z",
    }


def test_last_seen_is_utc_with_milliseconds_as_zigbee2mqtt_writes_it() -> None:
    assert iso_time(1714564800.25) == "2024-05-01T12:00:00.250Z"


def test_a_group_is_read_in_blocks_the_drive_accepts() -> None:
    # INVT drives answer at most 16 words per 03H: 3000H-3015H is two requests.
    assert blocks(0x3000, 22, 16) == (PollBlock(0x3000, 16), PollBlock(0x3010, 6))
    assert blocks(0x2100, 3, 16) == (PollBlock(0x2100, 3),)
    assert blocks(0x3000, 32, 16) == (PollBlock(0x3000, 16), PollBlock(0x3010, 16))
