"""What every part's Prometheus families share: the name prefix, a copy of a counter map taken
at one moment, and whether `_created` samples are exported.

Each part that publishes metrics owns them in a module of its own (`bus/metrics.py`,
`bus/request_metrics.py`, `tcp/metrics.py`, `mqtt/metrics.py`, `console/metrics.py`,
`store/metrics.py`): a prometheus_client `Collector` over the part's own counters, read at
scrape time. `gateway.metrics` serves them; it reads nothing of a part itself.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TypeVar

from prometheus_client import metrics as prometheus_client_metrics

PREFIX = "invt_gateway"
OTHER = "other"
"""The label value for anything unforeseen: label values stay a bounded set."""

K = TypeVar("K")
V = TypeVar("V")


def snapshot(mapping: Mapping[K, V]) -> dict[K, V]:
    """A copy, so the samples of one scrape come from one moment."""
    return dict(mapping)


def created_series() -> bool:
    """Whether prometheus_client exports `_created` samples (PROMETHEUS_DISABLE_CREATED_SERIES,
    or `disable_created_metrics()`): the same for these families as for its own."""
    return bool(getattr(prometheus_client_metrics, "_use_created", True))
