"""The Prometheus text of a registry, made a few hundred samples at a time on the event loop.

A scrape runs on the gateway's own loop (see `http_endpoint`), the loop that also ends every
line's gap. Made in one piece, it held that loop 1-3 ms with four drives; made a family at a time,
a gap still waited for the largest family's text: with 32 buses of four drives and 256 SCADA
clients the request-duration histogram is 1,792 samples, and its text held all 32 lines 25-33 ms
(five transactions' time at 115200 baud, on every line, at every scrape). Now a family's samples
are formatted `SAMPLES_PER_PIECE` at a time, the loop given back between pieces and families, and
the pieces' lines put back together as that family's one block.
"""

from __future__ import annotations

import asyncio
import copy
from collections.abc import Iterable

from prometheus_client import generate_latest
from prometheus_client.metrics_core import Metric
from prometheus_client.registry import Collector

SAMPLES_PER_PIECE = 100
"""About a millisecond of prometheus_client's formatting on a busy x86 core (5-12 us a sample):
the longest a line's gap waits for a scrape, beside what a collector's own `collect` takes."""


class _OneFamily(Collector):
    """What `generate_latest` formats: a collector of one family already collected."""

    def __init__(self, family: Metric) -> None:
        self.family = family

    def collect(self) -> Iterable[Metric]:
        return (self.family,)


async def exposition(registry: Collector) -> bytes:
    """The same bytes as `generate_latest(registry)`, with the loop's other work run between
    the families and between the pieces of a large one (their order and text are
    prometheus_client's own)."""
    parts = []
    for family in registry.collect():
        if len(family.samples) <= SAMPLES_PER_PIECE:
            parts.append(generate_latest(_OneFamily(family)))
        else:
            parts.append(await _in_pieces(family))
        await asyncio.sleep(0)  # a line's gap that ended meanwhile goes first
    return b"".join(parts)


async def _in_pieces(family: Metric) -> bytes:
    """One family's text, formatted a piece of its samples at a time.

    `generate_latest` writes a family as blocks, each a "# HELP" line, a "# TYPE" line and its
    sample lines: the family's own block, then one per OpenMetrics-only suffix (_created, _gsum,
    _gcount) in the suffixes' order. Each piece's text has the same blocks for the samples it
    holds: a block's lines are gathered under its header, piece after piece, in sample order."""
    blocks: dict[str, list[str]] = {}
    samples = family.samples
    for start in range(0, len(samples), SAMPLES_PER_PIECE):
        if start:
            await asyncio.sleep(0)
        piece = copy.copy(family)
        piece.samples = samples[start : start + SAMPLES_PER_PIECE]
        lines = generate_latest(_OneFamily(piece)).decode().splitlines(keepends=True)
        block: list[str] = []
        for index, line in enumerate(lines):
            # Label values escape their newlines: a line starting "# HELP " is a header, and
            # the "# TYPE " line after it is the header's too.
            if line.startswith("# HELP "):
                block = blocks.setdefault(line + lines[index + 1], [])
            elif not line.startswith("# TYPE "):
                block.append(line)
    own, *suffixed = blocks  # the family's own block first, as in every piece's text
    ordered = [own, *sorted(suffixed)]  # the suffixes' blocks by name, as generate_latest has them
    return "".join(header + "".join(blocks[header]) for header in ordered).encode()
