"""Our own share of each transaction: how much longer than the inter-frame gap the line stayed
silent between a reply and the next request, for a request the gap's end found waiting (the first
choice after a reply). One queued after the gap had ended but before the gateway woke for it counts
from its queueing: until then the line waited for a request, after it for the gateway. When the
gap's end finds nothing, the line goes idle, and the silence before the next request is a client's
(that look comes a lead of up to a few hundred microseconds before the gap ends,
`gateway.bus.gap_lead`: a request queued in that lead is taken for a client's pause too).

On a line that is never idle, a transaction is the drive's time (request, response delay, reply)
plus the gap that ends the previous one (t3.5) plus whatever the gateway adds on top: the wake-up
after the reply, choosing the next request, writing it. Only that last part is the gateway's, and
it is what this histogram holds (`invt_gateway_bus_excess_gap_seconds`).

Observing costs the bus a bisect and two additions per transaction: the counts are plain integers,
turned into a Prometheus histogram only when scraped.
"""

from __future__ import annotations

from gateway.buckets import Buckets

BOUNDS_S = (
    0.0,
    5e-6,
    10e-6,
    20e-6,
    30e-6,
    50e-6,
    75e-6,
    100e-6,
    150e-6,
    250e-6,
    500e-6,
    1e-3,
    2.5e-3,
    5e-3,
    10e-3,
)
"""Upper bounds (`le`) of the buckets, in seconds; the first, 0, counts gaps shorter than t3.5
(a gateway that does that corrupts frames: it must stay empty)."""


class GapExcess(Buckets):
    """A fixed-bucket histogram of excess gaps, written by the bus, read at scrape time."""

    __slots__ = ()

    def __init__(self) -> None:
        super().__init__(BOUNDS_S)


def quantile(buckets: list[tuple[float, int]], q: float) -> float:
    """The `q` quantile from cumulative (upper bound, count) buckets, interpolated linearly inside
    its bucket as Prometheus's `histogram_quantile` does; NaN when there is nothing."""
    if not buckets or buckets[-1][1] == 0:
        return float("nan")
    rank = q * buckets[-1][1]
    lower, below = 0.0, 0
    for bound, count in buckets:
        if count >= rank:
            if bound == float("inf"):
                return lower  # beyond the last bound: its value is all that can be said
            if count == below:
                return bound
            return lower + (bound - lower) * (rank - below) / (count - below)
        lower, below = bound, count
    return lower
