"""The buses' metric families, read at scrape time from each bus's own counters (`BusStats`,
`DriveStats`, the line's, the health tracker's): nothing is added to the hot path for them. The
buses write those counters on the event loop the scrape runs on, so a scrape always sees whole
transactions and needs no lock.

Bus utilisation is `rate(invt_gateway_bus_busy_seconds_total[1m])`: the fraction of time the
line was held by a transaction, response timeouts included (a dead drive costs line time too).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass

from prometheus_client.core import (
    CounterMetricFamily,
    GaugeMetricFamily,
    HistogramMetricFamily,
    InfoMetricFamily,
)
from prometheus_client.metrics_core import Metric
from prometheus_client.registry import Collector

from gateway.bus.bus import Bus, BusState
from gateway.bus.line import SerialLine
from gateway.metric_families import OTHER, PREFIX, snapshot

BROADCAST = "broadcast"


@dataclass(frozen=True, slots=True)
class DriveLabels:
    """A configured drive as its series are labelled."""

    drive: str
    bus: str
    address: int
    unit_id: int
    model: str


class DriveNames:
    """The drive label of (bus, address): the configured drive's name, `broadcast` for address
    0, `address_<n>` for an address no drive is configured at."""

    def __init__(self, drives: Sequence[DriveLabels]) -> None:
        self._names = {(d.bus, d.address): d.drive for d in drives}

    def __call__(self, bus: str, address: int) -> str:
        if address == 0:
            return BROADCAST
        return self._names.get((bus, address), f"address_{address}")


def exception_label(code: int) -> str:
    """01H-0BH by name of code; anything else a drive might send, "other"."""
    return f"{code:02X}" if 0x01 <= code <= 0x0B else OTHER


class BusMetrics(Collector):
    """Per bus, per line and per drive, from the buses of `buses` (a reload may put a new bus
    in the mapping: the next scrape reads that one)."""

    def __init__(self, buses: Mapping[str, Bus], drives: Sequence[DriveLabels]) -> None:
        self.buses = buses
        self.drives = drives
        self._name = DriveNames(drives)

    def relabel(self, drives: Sequence[DriveLabels]) -> None:
        """A reload changed the drives: the next scrape shows the new ones by name."""
        self.drives = drives
        self._name = DriveNames(drives)

    def collect(self) -> Iterable[Metric]:
        yield from self._buses()
        yield from self._drives()

    def _buses(self) -> Iterable[Metric]:
        buses = self.buses
        state = GaugeMetricFamily(
            f"{PREFIX}_bus_state", "1 for the bus's current state", labels=["bus", "state"]
        )
        depth = GaugeMetricFamily(
            f"{PREFIX}_bus_queue_depth", "Requests waiting for the line", labels=["bus"]
        )
        counters = {
            name: CounterMetricFamily(f"{PREFIX}_bus_{name}", doc, labels=["bus"])
            for name, doc in _BUS_COUNTERS.items()
        }
        busy = CounterMetricFamily(
            f"{PREFIX}_bus_busy_seconds",
            "Time the line was held by transactions, timeouts included (rate = utilisation)",
            labels=["bus"],
        )
        exchange = CounterMetricFamily(
            f"{PREFIX}_bus_exchange_seconds",
            "Time on the wire of answered exchanges: request, drive's delay, reply",
            labels=["bus"],
        )
        discarded = CounterMetricFamily(
            f"{PREFIX}_bus_discarded_bytes",
            "Bytes nobody asked for: late replies, echoes, noise",
            labels=["bus"],
        )
        excess = HistogramMetricFamily(
            f"{PREFIX}_bus_excess_gap_seconds",
            "Silence beyond the inter-frame gap (t3.5) between a reply and the next request, or "
            "since that request was queued if later, for a request the gap's end found waiting: "
            "the gateway's own share of each back-to-back transaction",
            labels=["bus"],
        )
        line = _LineFamilies()
        for name, bus in buses.items():
            excess.add_metric([name], bus.gap_excess.cumulative(), bus.gap_excess.sum_s)
            line.add(name, bus.line)
            for value in BusState:
                state.add_metric([name, str(value)], 1.0 if bus.state is value else 0.0)
            depth.add_metric([name], bus.queue_depth)
            stats = bus.stats
            for counter_name, family in counters.items():
                family.add_metric([name], getattr(stats, counter_name))
            busy.add_metric([name], sum(d.line_s for d in snapshot(bus.drive_stats).values()))
            exchange.add_metric([name], stats.busy_s)
            discarded.add_metric([name], bus.line.discarded_bytes)
        yield state
        yield depth
        yield from counters.values()
        yield busy
        yield exchange
        yield discarded
        yield excess
        yield from line.families()

    def _drives(self) -> Iterable[CounterMetricFamily | GaugeMetricFamily | InfoMetricFamily]:
        buses = self.buses
        info = InfoMetricFamily(f"{PREFIX}_drive", "Configured drives", labels=["bus", "drive"])
        online = GaugeMetricFamily(
            f"{PREFIX}_drive_online",
            "1 while the drive answers, 0 once isolated as offline",
            labels=["bus", "drive"],
        )
        for d in self.drives:
            details = {"address": str(d.address), "unit_id": str(d.unit_id), "model": d.model}
            info.add_metric([d.bus, d.drive], details)
            offline = buses[d.bus].health.is_offline(d.address)
            online.add_metric([d.bus, d.drive], 0.0 if offline else 1.0)
        yield info
        yield online
        labels = ["bus", "drive"]
        counters = {
            name: CounterMetricFamily(f"{PREFIX}_drive_{name}", doc, labels=labels)
            for name, doc in _DRIVE_COUNTERS.items()
        }
        busy = CounterMetricFamily(
            f"{PREFIX}_drive_busy_seconds",
            "Time the line was held for this drive, timeouts included",
            labels=labels,
        )
        bad = CounterMetricFamily(
            f"{PREFIX}_drive_bad_replies",
            "Replies that could not be the answer: crc, truncated, address, function, echo",
            labels=[*labels, "kind"],
        )
        exceptions = CounterMetricFamily(
            f"{PREFIX}_drive_exceptions",
            "Exception replies from the drive itself, by code (INVT: 06 frame error, ...)",
            labels=[*labels, "code"],
        )
        for bus_name, bus in buses.items():
            for address, stats in sorted(snapshot(bus.drive_stats).items()):
                if address == 0:
                    continue  # broadcasts are no drive's: bus_broadcasts_total counts them
                drive = self._name(bus_name, address)
                for counter_name, family in counters.items():
                    family.add_metric([bus_name, drive], getattr(stats, counter_name))
                busy.add_metric([bus_name, drive], stats.line_s)
                for kind, count in sorted(snapshot(stats.bad_replies).items()):
                    bad.add_metric([bus_name, drive, kind], count)
                by_label: dict[str, int] = {}
                for code, count in snapshot(stats.exceptions).items():
                    label = exception_label(code)
                    by_label[label] = by_label.get(label, 0) + count
                for label, count in sorted(by_label.items()):
                    exceptions.add_metric([bus_name, drive, label], count)
        yield from counters.values()
        yield busy
        yield bad
        yield exceptions


# The help texts are pinned with the names (tests/fixtures/metric_families.tsv): "resyncs"
# now counts markers of either kind (`gateway.bus.late_replies`), an 08H echo or a read; the
# Operations page says so.
_BUS_COUNTERS = {
    "requests": "Requests handed to the bus",
    "transactions": "Attempts put on the wire, retries included",
    "retries": "Attempts repeated after a timeout or a bad reply",
    "timeouts": "Attempts without a reply within the response timeout",
    "failed": "Requests answered 0x0B after every attempt failed",
    "broadcasts": "Broadcasts (address 0) sent",
    "coalesced": "Identical queued reads answered by one transaction",
    "queue_full": "Requests refused with 0x0A because the queue was full",
    "offline_rejected": "Requests answered 0x0B at once because their drive is offline",
    "port_errors": "Times the serial port failed (unplugged, I/O error)",
    "reopens": "Times the serial port was opened again after failing",
    "late_replies": "Replies that came after their request timed out, set aside, never an answer",
    "resyncs": "Diagnostic echoes (08H) sent after a timeout to catch up with late replies",
}
_DRIVE_COUNTERS = {
    "transactions": "Attempts put on the wire for this drive, retries included",
    "retries": "Attempts repeated for this drive",
    "timeouts": "Attempts this drive did not answer in time",
    "failed": "Requests to this drive answered 0x0B after every attempt failed",
    "late_replies": "Replies from this drive that came after their request timed out, set aside",
    "resyncs": "Diagnostic echoes (08H) sent to this drive after a timeout, before anything else",
}


_LINE_METRICS: tuple[
    tuple[str, type[CounterMetricFamily | GaugeMetricFamily], str, Callable[[SerialLine], float]],
    ...,
] = (
    (
        "line_garbage_bytes",
        CounterMetricFamily,
        "Bytes skipped before replies that could not start them (transceiver glitches, noise)",
        lambda line: line.garbage_bytes,
    ),
    (
        "line_echoes",
        CounterMetricFamily,
        "Requests the adapter handed back though the bus has echo: false (set echo: true)",
        lambda line: line.echoes,
    ),
    (
        "line_reply_silence_max_seconds",
        GaugeMetricFamily,
        "Longest silence seen inside a reply (an adapter delivering in bursts shows here)",
        lambda line: line.longest_reply_silence_s,
    ),
    (
        "line_gap_lead_seconds",
        GaugeMetricFamily,
        "How long before the inter-frame gap ends the line wakes to choose the next request "
        "(learnt from its wake-ups: about their 95th percentile of lateness while the event "
        "loop's lines spin within their budget, their lower quartile past it)",
        lambda line: line.gap_lead.lead_s,
    ),
    (
        "line_gap_spin_seconds",
        CounterMetricFamily,
        "CPU time spent waiting out the gap's last microseconds after an early wake-up",
        lambda line: line.gap_lead.spun_s,
    ),
)
"""Per line: what its hardware does to replies (glitches, echoes, bursts) and what keeping its
gap costs (`gateway.bus.line`): name, kind, help, and how to read it off the line."""


class _LineFamilies:
    """The `_LINE_METRICS` families, one sample per bus."""

    def __init__(self) -> None:
        self._families = [
            (kind(f"{PREFIX}_{name}", doc, labels=["bus"]), read)
            for name, kind, doc, read in _LINE_METRICS
        ]

    def add(self, bus: str, line: SerialLine) -> None:
        for family, read in self._families:
            family.add_metric([bus], read(line))

    def families(self) -> Iterable[CounterMetricFamily | GaugeMetricFamily]:
        return [family for family, _ in self._families]
