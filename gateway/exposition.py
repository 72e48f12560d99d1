"""The Prometheus text of a registry, made a metric family at a time on the event loop.

A scrape runs on the gateway's own loop (see `http_endpoint`), the loop that also ends every
line's gap. Made in one piece, it held that loop 1-3 ms with four drives (more with more drives
and buses): a gap ending in those milliseconds sent its frame that much late, once per scrape.
Made a family at a time with the loop given back in between, a gap waits at most for one
family's text.
"""

from __future__ import annotations

import asyncio
from collections.abc import Iterable

from prometheus_client import generate_latest
from prometheus_client.metrics_core import Metric
from prometheus_client.registry import Collector


class _OneFamily(Collector):
    """What `generate_latest` formats: a collector of one family already collected."""

    def __init__(self, family: Metric) -> None:
        self.family = family

    def collect(self) -> Iterable[Metric]:
        return (self.family,)


async def exposition(registry: Collector) -> bytes:
    """The same bytes as `generate_latest(registry)`, with the loop's other work run between
    the families (their order and text are prometheus_client's own)."""
    parts = []
    for family in registry.collect():
        parts.append(generate_latest(_OneFamily(family)))
        await asyncio.sleep(0)  # a line's gap that ended meanwhile goes first
    return b"".join(parts)
