"""What a bus counts (`BusStats`, `DriveStats`): everything that happened on the wire is counted
once, for its address, and the bus's totals that metrics and the console show are the sums of
those, worked out when read, so they can never disagree with the drives' own."""

from __future__ import annotations

from collections import Counter

from gateway.bus.stats import BusStats, DriveStats


def test_the_buses_totals_are_the_sums_of_its_drives_counters_as_they_are_now() -> None:
    stats = BusStats()
    assert (stats.transactions, stats.retries, stats.timeouts, stats.failed) == (0, 0, 0, 0)
    assert (stats.late_replies, stats.resyncs) == (0, 0)
    assert stats.bad_replies == Counter()
    assert stats.exceptions == Counter()
    stats.drives[1] = DriveStats(
        transactions=10,
        retries=2,
        timeouts=3,
        bad_replies=Counter(crc=1),
        exceptions=Counter({2: 1}),
        failed=1,
        late_replies=1,
        resyncs=2,
    )
    stats.drives[0] = DriveStats(transactions=4)  # broadcasts: on the wire too
    stats.drives[7] = DriveStats(
        transactions=5, timeouts=5, bad_replies=Counter(crc=2, truncated=1), failed=2, resyncs=1
    )
    assert stats.transactions == 19
    assert (stats.retries, stats.timeouts, stats.failed) == (2, 8, 3)
    assert (stats.late_replies, stats.resyncs) == (1, 3)
    assert stats.bad_replies == Counter(crc=3, truncated=1)
    assert stats.exceptions == Counter({2: 1})
    # Counted later, for one drive: the totals follow at once, nothing else to keep in step.
    stats.drives[7].transactions += 1
    stats.drives[7].bad_replies["address"] += 1
    assert stats.transactions == 20
    assert stats.bad_replies == Counter(crc=3, truncated=1, address=1)
    # Read as sums, never handed out: changing what was read changes no drive's count.
    stats.bad_replies["crc"] += 100
    assert stats.drives[1].bad_replies == Counter(crc=1)
