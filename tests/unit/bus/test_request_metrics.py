"""The per-request metrics a dashboard reads (`invt_gateway_requests_total`, the exceptions, the
broadcasts, the latency histogram), as Prometheus's text format shows them after a few requests,
before any, and across a reload that renames a drive."""

from __future__ import annotations

from prometheus_client import CollectorRegistry, generate_latest
from prometheus_client.parser import text_string_to_metric_families

from gateway.bus import RequestDone
from gateway.bus.metrics import DriveLabels
from gateway.bus.request_metrics import MAX_SERIES_KEYS, RequestMetrics

PUMP = DriveLabels("pump1", "line1", 1, 1, "gd350")
Samples = dict[tuple[str, frozenset[tuple[str, str]]], float]


def scrape(
    metrics: RequestMetrics,
) -> tuple[str, dict[tuple[str, frozenset[tuple[str, str]]], float]]:
    """The text a scrape gets, and each sample by (name, labels)."""
    registry = CollectorRegistry(auto_describe=True)
    registry.register(metrics)
    text = generate_latest(registry).decode()
    samples = {
        (sample.name, frozenset(sample.labels.items())): sample.value
        for family in text_string_to_metric_families(text)
        for sample in family.samples
    }
    return text, samples


def labels(**values: str) -> frozenset[tuple[str, str]]:
    return frozenset(values.items())


def test_requests_are_counted_by_source_function_and_code_with_their_latency() -> None:
    metrics = RequestMetrics([PUMP])
    metrics.observe(*RequestDone("line1", 1, 3, "tcp:10.0.0.5:50123", 0.004, None))
    metrics.observe(*RequestDone("line1", 1, 3, "tcp:10.0.0.6:50124", 0.03, 0x02))
    metrics.observe(*RequestDone("line1", 0, 6, "mqtt", 0.1, None))
    _, samples = scrape(metrics)
    tcp = {"bus": "line1", "drive": "pump1", "source": "tcp"}
    assert samples["invt_gateway_requests_total", labels(**tcp, function="03")] == 2
    assert samples["invt_gateway_request_exceptions_total", labels(**tcp, code="02")] == 1
    broadcast = labels(bus="line1", source="mqtt", function="06")
    assert samples["invt_gateway_broadcast_requests_total", broadcast] == 1
    bucket = "invt_gateway_request_duration_seconds_bucket"
    assert samples[bucket, labels(**tcp, le="0.005")] == 1
    assert samples[bucket, labels(**tcp, le="0.05")] == 2
    assert samples[bucket, labels(**tcp, le="+Inf")] == 2
    assert samples["invt_gateway_request_duration_seconds_count", labels(**tcp)] == 2
    assert abs(samples["invt_gateway_request_duration_seconds_sum", labels(**tcp)] - 0.034) < 1e-9
    assert ("invt_gateway_requests_created", labels(**tcp, function="03")) in samples
    assert ("invt_gateway_request_duration_seconds_created", labels(**tcp)) in samples


def test_before_any_request_the_families_are_there_without_samples() -> None:
    text, samples = scrape(RequestMetrics([PUMP]))
    assert "# TYPE invt_gateway_requests_total counter" in text
    assert "# TYPE invt_gateway_request_duration_seconds histogram" in text
    assert samples == {}
    assert "_created" not in text  # no empty family of its own either


def test_a_reload_that_renames_a_drive_keeps_what_was_counted_under_the_old_name() -> None:
    metrics = RequestMetrics([PUMP])
    metrics.observe(*RequestDone("line1", 1, 3, "poll", 0.01, None))
    metrics.relabel([DriveLabels("pump_north", "line1", 1, 1, "gd350")])
    metrics.observe(*RequestDone("line1", 1, 3, "poll", 0.01, None))
    _, samples = scrape(metrics)
    for drive in ("pump1", "pump_north"):
        series = labels(bus="line1", drive=drive, source="poll", function="03")
        assert samples["invt_gateway_requests_total", series] == 1


def test_clients_that_come_and_go_all_day_are_counted_in_bounded_memory() -> None:
    """Each connection is a client of its own ("tcp:<peer>"): ten thousand of them, a read
    each, all counted under their one series, and what the metrics remember per client stays
    bounded (`MAX_SERIES_KEYS`)."""
    metrics = RequestMetrics([PUMP])
    clients = 10_000
    for n in range(clients):
        metrics.observe(
            *RequestDone("line1", 1, 3, f"tcp:10.0.{n // 250}.{n % 250}:502", 0.004, None)
        )
    _, samples = scrape(metrics)
    tcp = {"bus": "line1", "drive": "pump1", "source": "tcp"}
    assert samples["invt_gateway_requests_total", labels(**tcp, function="03")] == clients
    assert samples["invt_gateway_request_duration_seconds_count", labels(**tcp)] == clients
    assert len(metrics._series) <= MAX_SERIES_KEYS
