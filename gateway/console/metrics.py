"""The console's metric families, read at scrape time: connections closed for a request too
slow to arrive, requests refused for what they sent, and login attempts by result."""

from __future__ import annotations

from collections.abc import Iterable

from prometheus_client.core import CounterMetricFamily
from prometheus_client.registry import Collector

from gateway.console.bad_requests import REFUSED_STATUSES
from gateway.console.feature import ConsoleFeature
from gateway.metric_families import PREFIX


class ConsoleMetrics(Collector):
    def __init__(self, console: ConsoleFeature) -> None:
        self.console = console

    def collect(self) -> Iterable[CounterMetricFamily]:
        timeouts = CounterMetricFamily(
            f"{PREFIX}_console_request_timeouts",
            "Console connections closed: a request's head or body not there within "
            "console.request_timeout_s",
            labels=["phase"],
        )
        closed = self.console.deadlines.closed
        timeouts.add_metric(["head"], closed.head)
        timeouts.add_metric(["body"], closed.body)
        yield timeouts
        refused = CounterMetricFamily(
            f"{PREFIX}_console_bad_requests",
            "Console requests refused for what they sent, by HTTP status: 414 a request line "
            "too long, 413 a body too large, 400 a request or body that does not parse",
            labels=["status"],
        )
        by_status = self.console.bad_requests.by_status
        for status in REFUSED_STATUSES:
            refused.add_metric([str(status)], by_status[status])
        yield refused
        console = self.console.console
        if console is None:  # not started (yet)
            return
        logins = CounterMetricFamily(
            f"{PREFIX}_console_logins",
            "Console login attempts by result: ok, failed (wrong name or password), throttled "
            "(refused before the password was checked: that name and address must wait)",
            labels=["result"],
        )
        counts = console.logins
        for result in ("ok", "failed", "throttled"):
            logins.add_metric([result], getattr(counts, result))
        yield logins
