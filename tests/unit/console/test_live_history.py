"""The console's live ring of a drive's values: the last 15 minutes, however often it is
polled."""

from __future__ import annotations

from gateway.console.live import HISTORY_S, DriveHistory


def test_a_drive_polled_every_three_seconds_keeps_its_last_15_minutes_only() -> None:
    history = DriveHistory()
    for n in range(1200):  # an hour
        history.add(3.0 * n, {"output_frequency_hz": float(n)})
    times = [at for at, _ in history.points]
    assert times[-1] - times[0] <= HISTORY_S
    assert len(times) == 301  # 15 minutes of a point every 3 s, both ends
    assert history.points[-1][1] == {"output_frequency_hz": 1199.0}


def test_a_point_a_second_fills_the_ring_and_no_more() -> None:
    history = DriveHistory()
    for n in range(3600):
        history.add(float(n), {"bus_voltage_v": 540.0})
    assert len(history.points) == 901
    assert history.points[0][0] == 3599.0 - HISTORY_S
