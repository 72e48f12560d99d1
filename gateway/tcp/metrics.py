"""The Modbus-TCP server's metric families, read at scrape time from its `TcpStats` and its
access policy's refusals: clients connected, connections and requests counted, requests answered
at the front door by reason, refusals by `modbus_tcp.access` rule."""

from __future__ import annotations

from collections.abc import Iterable

from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily
from prometheus_client.registry import Collector

from gateway.metric_families import PREFIX
from gateway.modbus.request_checks import Reason
from gateway.tcp.access import AccessPolicy
from gateway.tcp.server import ModbusTcpServer


class TcpMetrics(Collector):
    def __init__(self, server: ModbusTcpServer) -> None:
        self.server = server

    def collect(self) -> Iterable[CounterMetricFamily | GaugeMetricFamily]:
        stats = self.server.stats
        clients = GaugeMetricFamily(f"{PREFIX}_tcp_clients", "Modbus-TCP clients connected")
        clients.add_metric([], len(stats.active))
        yield clients
        for name, doc in _TCP_COUNTERS.items():
            yield CounterMetricFamily(f"{PREFIX}_tcp_{name}", doc, value=getattr(stats, name))
        malformed = CounterMetricFamily(
            f"{PREFIX}_tcp_malformed_requests",
            "Requests answered at the front door without bus time (01H or 03H), by reason",
            labels=["reason"],
        )
        counts = dict(stats.malformed_requests)
        for reason in Reason:  # every reason, from the start: a fixed set of series
            malformed.add_metric([str(reason)], counts.get(reason, 0))
        yield malformed
        access = self.server.access  # a reload may set rules, or take them away
        if access is not None:
            yield _denied_by_rule(access)


def _denied_by_rule(access: AccessPolicy) -> CounterMetricFamily:
    denied = CounterMetricFamily(
        f"{PREFIX}_tcp_denied_by_rule",
        "Modbus-TCP requests refused by each modbus_tcp.access rule",
        labels=["rule"],
    )
    for rule, count in zip(access.rules, list(access.denied), strict=True):
        denied.add_metric([rule.label], count)
    return denied


_TCP_COUNTERS = {
    "accepted": "Modbus-TCP connections accepted",
    "refused": "Modbus-TCP connections refused (limit or allowed_networks)",
    "requests": "Modbus-TCP requests received",
    "exceptions": "Modbus-TCP requests answered with an exception",
    "malformed": "Connections closed for a malformed MBAP frame",
    "idle_closed": "Connections closed after the idle timeout",
    "denied": "Requests refused by modbus_tcp.read_only or modbus_tcp.access",
    "evicted": "Connections closed to make room for a new one: they had never completed a request",
    "slow_closed": "Connections closed for a frame not completed in time, or no first request",
    "write_limited": "Writes answered 0AH: the client had max_queued_writes_per_client waiting",
    "tls_handshake_timeouts": (
        "TLS connections closed with their handshake not done within first_request_timeout_s"
    ),
    "tls_handshakes_failed": "TLS handshakes that failed (no or an untrusted client certificate)",
}
