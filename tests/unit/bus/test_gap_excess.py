"""The excess-gap histogram (`invt_gateway_bus_excess_gap_seconds`): our own share of each
transaction, counted into fixed buckets, read as Prometheus's cumulative buckets, and the
quantile the bench reports from them."""

from __future__ import annotations

import math

from gateway.bus.gap_excess import BOUNDS_S, GapExcess, quantile


def test_each_gap_lands_in_the_first_bucket_that_holds_it() -> None:
    excess = GapExcess()
    for seconds in (-0.0001, 0.0, 4e-6, 5e-6, 40e-6, 0.02):
        excess.observe(seconds)
    buckets = dict(excess.cumulative())
    assert buckets["0.0"] == 2  # shorter than t3.5 (a frame-corrupting gateway), and exactly 0
    assert buckets["5e-06"] == 4  # an upper bound is inclusive, as Prometheus's `le`
    assert buckets["5e-05"] == 5
    assert buckets["0.01"] == 5
    assert buckets["+Inf"] == excess.count == 6
    assert math.isclose(excess.sum_s, 0.019949)  # the early one counts against it


def test_the_buckets_are_cumulative_in_order_of_their_bounds_with_inf_last() -> None:
    excess = GapExcess()
    excess.observe(1e-3)
    names = [le for le, _ in excess.cumulative()]
    assert names == [repr(b) for b in BOUNDS_S] + ["+Inf"]
    counts = [count for _, count in excess.cumulative()]
    assert counts == sorted(counts)


def test_the_quantile_is_interpolated_inside_its_bucket_as_prometheus_does() -> None:
    buckets = [(0.0, 0), (10e-6, 50), (20e-6, 100), (float("inf"), 100)]
    assert math.isclose(quantile(buckets, 0.5), 10e-6)
    assert math.isclose(quantile(buckets, 0.75), 15e-6)
    assert math.isclose(quantile(buckets, 0.25), 5e-6)


def test_a_quantile_beyond_the_last_bound_is_that_bound_and_nothing_is_nan() -> None:
    assert quantile([(10e-6, 1), (float("inf"), 10)], 0.99) == 10e-6
    assert math.isnan(quantile([(10e-6, 0), (float("inf"), 0)], 0.5))
    assert math.isnan(quantile([], 0.5))
