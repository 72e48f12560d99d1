"""Which drives are offline and when they are probed: a drive that fell silent waits out a growing
backoff; drives that went offline only because the port did are probed as soon as it is back,
with the line's usual retries."""

from __future__ import annotations

import random

from gateway.bus.health import HealthTracker


def tracker() -> HealthTracker:
    return HealthTracker(
        offline_after=3, probe_initial_s=2.0, probe_max_s=30.0, rng=random.Random(1)
    )


def test_a_silent_drive_goes_offline_and_waits_a_growing_backoff() -> None:
    health = tracker()
    for _ in range(3):
        health.record_failure(7, now=100.0)
    assert health.is_offline(7)
    assert not health.lost_with_line(7)
    assert health.due_probes(100.0) == []
    first = health.next_probe_at()
    assert first is not None
    assert 101.6 <= first <= 102.0
    health.record_failure(7, now=first)  # its probe failed too: twice as long
    second = health.next_probe_at()
    assert second is not None
    assert second - first >= 3.2
    assert health.line_back(second) == []  # a port coming back is no news about this one


def test_drives_taken_offline_by_the_port_are_probed_when_it_is_back() -> None:
    health = tracker()
    health.record_answer(1)
    health.record_answer(2)
    assert health.force_offline(1, now=100.0)
    assert health.force_offline(2, now=100.0)
    assert health.lost_with_line(1)
    assert health.due_probes(100.5) == []  # the port is still away: nothing to probe yet
    assert sorted(health.line_back(100.5)) == [1, 2]
    assert sorted(health.due_probes(100.5)) == [1, 2]


def test_a_drive_still_silent_on_the_reopened_port_is_treated_as_dead() -> None:
    health = tracker()
    health.record_answer(1)
    health.force_offline(1, now=100.0)
    health.line_back(101.0)
    health.record_failure(1, now=101.1)  # the probe, retries and all, got nothing
    assert health.is_offline(1)
    assert not health.lost_with_line(1)
    health.record_answer(1)
    assert not health.is_offline(1)


def test_the_bus_can_tell_at_a_glance_whether_any_drive_is_offline() -> None:
    """Asked once per transaction (is a probe worth looking for?): it must follow every way in
    and out of offline, or a dead drive would never be probed again."""
    health = tracker()
    assert not health.any_offline
    for _ in range(3):
        health.record_failure(7, now=100.0)
    health.record_failure(7, now=200.0)  # offline already: still one drive offline
    assert health.any_offline
    for address in (1, 7):
        health.force_offline(address, now=300.0)  # the port went: 1 goes too, 7 already was
    health.record_answer(7)
    assert health.any_offline  # 1 is still offline
    health.record_answer(1)
    health.record_answer(1)  # answering again changes nothing
    assert not health.any_offline
    assert health.due_probes(1e9) == []
