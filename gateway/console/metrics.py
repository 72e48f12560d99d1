"""The console's metric families, read at scrape time: connections closed for a request too
slow to arrive, and login attempts by result."""

from __future__ import annotations

from collections.abc import Iterable

from prometheus_client.core import CounterMetricFamily
from prometheus_client.registry import Collector

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
