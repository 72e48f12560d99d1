"""How the line's time is shared while reads wait: writes at most half of it, broadcasts at most a
tenth, an old burst forgotten (half-life 2 s), and no limit at all for a share of 1."""

from __future__ import annotations

from gateway.bus.line_share import HALF_LIFE_S, LineShares, LineUse, ShareMeter


def test_writes_may_go_first_until_they_have_had_half_the_line() -> None:
    meter = ShareMeter(LineShares(write_share=0.5))
    assert meter.writes_may_go(now=0.0)  # nothing used yet
    meter.charge(LineUse.OTHER, 0.1, now=0.0)
    meter.charge(LineUse.WRITE, 0.09, now=0.0)
    assert meter.writes_may_go(now=0.0)
    meter.charge(LineUse.WRITE, 0.02, now=0.0)  # 0.11 of 0.21: over half
    assert not meter.writes_may_go(now=0.0)


def test_broadcasts_count_as_writes_and_have_their_own_smaller_share() -> None:
    meter = ShareMeter(LineShares(write_share=0.5, broadcast_share=0.1))
    meter.charge(LineUse.OTHER, 0.9, now=0.0)
    meter.charge(LineUse.BROADCAST, 0.12, now=0.0)  # 12 % of the line
    assert not meter.broadcasts_may_go(now=0.0)
    assert meter.writes_may_go(now=0.0)  # writes, broadcasts included, are at 12 % of 50 %
    meter.charge(LineUse.WRITE, 1.0, now=0.0)
    assert not meter.writes_may_go(now=0.0)


def test_a_broadcast_waits_while_writes_are_over_their_share() -> None:
    meter = ShareMeter(LineShares(write_share=0.5, broadcast_share=0.5))
    meter.charge(LineUse.WRITE, 1.0, now=0.0)
    assert not meter.broadcasts_may_go(now=0.0)  # no broadcast yet, but the writes had it all


def test_an_old_burst_of_writes_is_forgotten() -> None:
    meter = ShareMeter(LineShares(write_share=0.5))
    meter.charge(LineUse.WRITE, 1.0, now=0.0)
    assert not meter.writes_may_go(now=0.0)
    # Ten half-lives later the burst weighs a thousandth: fresh reads outweigh it.
    meter.charge(LineUse.OTHER, 0.01, now=10 * HALF_LIFE_S)
    assert meter.writes_may_go(now=10 * HALF_LIFE_S)


def test_a_share_of_one_means_writes_always_go_first() -> None:
    meter = ShareMeter(LineShares(write_share=1.0, broadcast_share=1.0))
    meter.charge(LineUse.BROADCAST, 5.0, now=0.0)
    assert meter.writes_may_go(now=0.0)
    assert meter.broadcasts_may_go(now=0.0)


def test_hours_of_line_time_weigh_as_their_last_minutes_without_overflowing() -> None:
    """Charges are weighed by a weight that grows with time (nothing decays per charge); it is
    brought back to scale long before a float overflows, and a monotonic clock that starts far
    from 0 (a machine up for weeks) is no different."""
    meter = ShareMeter(LineShares(write_share=0.5))
    start = 3e6
    meter.charge(LineUse.WRITE, 1.0, now=start)
    for minute in range(1, 121):  # two hours of reads, a charge a minute: many rebases
        meter.charge(LineUse.OTHER, 0.001, now=start + 60.0 * minute)
    assert meter.writes_may_go(now=start + 7200.0)  # the old write is forgotten
    meter.charge(LineUse.WRITE, 0.01, now=start + 7200.0)  # ten times the last read
    assert not meter.writes_may_go(now=start + 7200.0)
