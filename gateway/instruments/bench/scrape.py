"""The gateway's own figures, read from its /metrics between the bench's measurements."""

from __future__ import annotations

import asyncio
import urllib.request

from prometheus_client.parser import text_string_to_metric_families

EXCESS_GAP = "invt_gateway_bus_excess_gap_seconds"


async def excess_gap_buckets(metrics_port: int) -> dict[float, int]:
    """`bus_excess_gap_seconds` now, every bus summed: upper bound -> cumulative count."""

    def get() -> str:
        url = f"http://127.0.0.1:{metrics_port}/metrics"
        with urllib.request.urlopen(url, timeout=5) as response:
            return str(response.read().decode())

    text = await asyncio.to_thread(get)
    buckets: dict[float, int] = {}
    for family in text_string_to_metric_families(text):
        if family.name != EXCESS_GAP:
            continue
        for sample in family.samples:
            if sample.name == EXCESS_GAP + "_bucket":
                le = float(sample.labels["le"])
                buckets[le] = buckets.get(le, 0) + int(sample.value)
    return buckets
