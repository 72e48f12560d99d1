"""The benchmark's table, and its JSON for machines."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from gateway.instruments.bench.cases import OPCUA, SCADA_ALONE, SCADA_POLLED, CaseResult
from gateway.instruments.simulator.line import WAKE_EARLY_S

COLUMNS = (
    ("case", "{:<40}"),
    ("baud", "{:>6}"),
    ("words", "{:>5}"),
    ("clients", "{:>7}"),
    ("client tx/s", "{:>11.1f}"),
    ("p50 ms", "{:>7.1f}"),
    ("p99 ms", "{:>7.1f}"),
    ("errors", "{:>6}"),
    ("wrong", "{:>5}"),
    ("bus tx/s", "{:>8.1f}"),
    ("bus util", "{:>8.1%}"),
    ("wire max/s", "{:>10.1f}"),
    ("of max", "{:>7.1%}"),
    ("t3.5 viol", "{:>9}"),
    ("gap+ p50 us", "{:>11.0f}"),
    ("gap+ p99 us", "{:>11.0f}"),
    ("gap+ n", "{:>6}"),
    ("ovh us/tx", "{:>9.0f}"),
    ("heard+ p50 us", "{:>13.0f}"),
    ("drive late p50 us", "{:>17.0f}"),
    ("worst line", "{:>10.1%}"),
    ("vs 1 line", "{:>9.1f}"),
    ("CPU us/tx", "{:>9.0f}"),
    ("CPU us/ans", "{:>10.0f}"),
    ("CPU", "{:>6.1%}"),
    ("peak RSS MB", "{:>11.1f}"),
    ("RSS MiB", "{:>7.1f}"),
    ("drives CPU", "{:>10.1%}"),
    ("CPU waited", "{:>10.1%}"),
    ("drives waited", "{:>13.1%}"),
    ("host steal", "{:>10.1%}"),
)
POINTS_FROM_ONE_LINE = 2.0
"""The lines cases' target: each line within this many percentage points of one line alone."""


def row(result: CaseResult) -> dict[str, Any]:
    case = result.case
    return {
        "case": case.name,
        "baud": case.baudrate,
        "words": case.words,
        "clients": case.clients,
        "client tx/s": result.client_per_s,
        "p50 ms": result.latency_ms(0.50),
        "p99 ms": result.latency_ms(0.99),
        "errors": result.load.errors,
        "wrong": result.load.wrong,
        "bus tx/s": result.bus_per_s,
        "bus util": result.utilisation,
        "wire max/s": result.wire_max_per_s,
        # Served to clients over what the wire can carry: above 100 % only by coalescing/cache.
        "of max": result.client_per_s / result.wire_max_per_s,
        "t3.5 viol": result.gap_violations,
        # The gateway's own share: silence beyond t3.5 before a request that was waiting.
        "gap+ p50 us": result.excess_gap_us(0.50),
        "gap+ p99 us": result.excess_gap_us(0.99),
        "gap+ n": result.excess_gap_count,
        # Measured time per transaction on a line minus the wire's: gaps, wake-ups, the pty.
        "ovh us/tx": result.overhead_us,
        # Where the overhead goes besides the gateway's share: the silence beyond t3.5 the
        # simulated drives heard after each reply (gap+ plus reading the reply and the pty
        # relay), and how late the drives themselves answered (their thread woken late).
        "heard+ p50 us": result.heard_gap_us(0.50),
        "drive late p50 us": result.drive_late_us(0.50),
        "worst line": min(result.line_shares, default=float("nan")),
        # Lines cases: the mean line's share of the wire minus one line's alone, in points.
        "vs 1 line": result.points_from_one_line,
        # The same with the time lines waited for late simulated drives aside (JSON only).
        "vs 1 line, drives aside": result.points_from_one_line_drives_aside,
        "CPU us/tx": result.cpu_per_transaction_us,
        "CPU us/ans": result.cpu_per_answer_us,
        "CPU": result.cpu_share,
        "peak RSS MB": result.peak_rss_mb,  # in MiB, as "RSS MiB"
        "RSS MiB": result.rss_mb,  # at the end of the measured time
        # The simulated drives' processes (the harness, not the gateway): near 100 % of a
        # core, one thread serving every line no longer answers on time.
        "drives CPU": result.simulator_cpu_share,
        # How long each waited for a core, runnable but not running, over the measured time:
        # well above nothing, the machine (its other work) was what held the line back.
        "CPU waited": result.run_queue_s / result.elapsed_s,
        "drives waited": result.simulator_run_queue_s / result.elapsed_s,
        # What the hypervisor took from this machine's processors (steal): on a shared host
        # above a percent or so, every wake-up here comes late and the line loses for it.
        "host steal": result.host_steal_share,
        # The opcua case's clients (JSON only): monitored items per session, notifications.
        "opcua items": result.opcua.get("items", 0),
        "opcua notifications": result.opcua.get("notifications", 0),
        "opcua polled items": result.opcua.get("polled", 0),
    }


def header() -> str:
    cells = []
    for name, fmt in COLUMNS:
        width = int("".join(c for c in fmt.split(":")[1] if c.isdigit() or c == ".").split(".")[0])
        cells.append(name.rjust(width) if ">" in fmt else name.ljust(width))
    return "  ".join(cells)


def format_row(values: dict[str, Any]) -> str:
    return "  ".join(fmt.format(values[name]) for name, fmt in COLUMNS)


def summary(results: list[CaseResult]) -> list[str]:
    """The benchmark's targets, each as a sentence with its figure."""
    lines = []
    by_case = {r.case: r for r in results}
    alone = {r.case.baudrate: r for r in results if r.case.name == "flood: 8 readers alone"}
    unpolled = {r.case.baudrate: r for r in results if r.case.name == SCADA_ALONE}
    without_opcua = {
        r.case.baudrate: r for r in results if r.case.name.startswith(OPCUA) and not r.case.opcua
    }
    for result in results:
        case = result.case
        share = result.bus_per_s / result.wire_max_per_s
        gaps = (
            f"excess gap median {result.excess_gap_us(0.5):.0f} us, "
            f"p99 {result.excess_gap_us(0.99):.0f} us (targets <= 50 and <= 250 us)"
            + (
                f"; the p99 is the slowest of {result.excess_gap_count} transactions"
                if 0 < result.excess_gap_count < 100
                else ""
            )
        )
        if case.name.startswith(OPCUA):
            if case.opcua:
                lines.append(opcua_sentence(result, without_opcua.get(case.baudrate)))
        elif case.name == SCADA_POLLED:
            lines.append(scada_sentence(result, unpolled.get(case.baudrate)))
        elif case.name == SCADA_ALONE:
            continue  # said with the polled case
        elif case.flood:
            base = alone.get(case.baudrate)
            was = f"{base.latency_ms(0.99):.1f} ms" if base else "not measured"
            lines.append(
                f"{case.baudrate} baud, {case.name}: the readers' p99 {result.latency_ms(0.99):.1f}"
                f" ms (alone: {was}), {result.client_per_s:.1f} reads/s answered"
            )
        elif case.many_lines:
            lines.append(lines_sentence(result, gaps))
        elif case.no_wire:
            lines.append(
                f"{case.baudrate} baud, {case.name}: gateway CPU "
                f"{result.cpu_per_transaction_us:.0f} us per bus transaction (target <= 300 us), "
                f"{result.bus_per_s:.0f} transactions/s ({share:.1%} of what the t3.5 gap alone "
                f"allows), {result.gap_violations} t3.5 violations"
            )
        elif case.relay_ms:
            lines.append(
                f"{case.baudrate} baud, {case.name}: bus at {share:.1%} of what the wire and "
                f"the relay allow ({case.relay_ms:g} ms each way counted in the maximum; target "
                f">= 96 %), {result.gap_violations} t3.5 violations; {gaps}; the drives heard "
                f"{result.heard_gap_us(0.5):.0f} us beyond t3.5 and the relay before each "
                f"request at the median (the gateway's excess gap, its reading of the reply "
                f"and the pty's two hops) and answered {result.drive_late_us(0.5):.0f} us late"
            )
        elif case.fast:
            lines.append(
                f"{case.baudrate} baud, {case.name}: bus at {share:.1%} of the wire maximum "
                f"(target >= 93 %), {result.gap_violations} t3.5 violations; {gaps}"
            )
        elif case.dead:
            alive = by_case.get(case.baseline())
            if alive is not None:
                # Each client asks one drive: with one dead, the healthy drives' clients may
                # have the whole line. What it answered them, against what it answered all
                # clients with every drive alive, is what the dead drive costs the line.
                kept = result.per_s_of(result.healthy_units) / max(alive.client_per_s, 1e-9)
                lines.append(
                    f"{case.baudrate} baud, {case.name}: the healthy drives get {kept:.0%} of "
                    "what the line answered with all four alive (target >= 80 %)"
                )
        elif case.same_registers:
            ratio = result.client_per_s / result.wire_max_per_s
            how = "with the poll cache" if case.cache else "by coalescing alone (target >= 5x)"
            lines.append(
                f"{case.baudrate} baud, {case.name}: {ratio:.1f}x the wire maximum served {how}"
            )
        elif case.adapter_args:
            lines.append(
                f"{case.baudrate} baud, {case.name}: {result.bus_per_s:.1f} transactions/s, "
                f"{share:.1%} of what the line and the adapter allow, {result.load.errors} errors, "
                f"{result.load.wrong} wrong values (target: 0 errors, the throughput the adapter "
                "allows)"
            )
        elif not case.cache and case.drives == 4:
            lines.append(
                f"{case.baudrate} baud, {case.name}: bus at {share:.1%} of the wire maximum, "
                f"{result.gap_violations} t3.5 violations (target >= 95 %); "
                f"gateway CPU {result.cpu_per_transaction_us:.0f} us per bus transaction "
                f"(target <= 300 us); {gaps}"
            )
        elif case.drives > 4:
            lines.append(
                f"{case.baudrate} baud, {case.name}: peak RSS {result.peak_rss_mb:.1f} MB "
                "(target <= 60 MB)"
            )
    return lines


STEAL_NOTICEABLE = 0.01
"""Steal above this share of the processors' time: the figures measure the host too."""


def host_sentence(results: Sequence[CaseResult]) -> str:
    """How much of the processors' time the hypervisor took while the cases were measured."""
    shares = [r.host_steal_share for r in results if not math.isnan(r.host_steal_share)]
    if not shares:
        return "the host's steal time is not known here (no /proc/stat)"
    worst = max(shares)
    said = (
        f"the hypervisor took {min(shares):.1%}-{worst:.1%} of this machine's processor time "
        "while the cases were measured (steal)"
    )
    if worst > STEAL_NOTICEABLE:
        said += (
            f": above {STEAL_NOTICEABLE:.0%} every wake-up comes late, and a case's line figures "
            "fall with it (compare the rows' host steal)"
        )
    return said


def lines_sentence(result: CaseResult, gaps: str) -> str:
    """A lines case against its targets: each line within two points of one line alone, the
    gateway below one core; its memory; where the rest of the time goes."""
    case = result.case
    head = f"{case.baudrate} baud, {case.name}: "
    if case.lines == 1:
        return (
            f"{head}the reference of the lines cases, {result.utilisation:.1%} of the wire "
            f"maximum; gateway CPU {result.cpu_share:.0%} of a core, RSS {result.rss_mb:.1f} MiB"
        )
    points = result.points_from_one_line
    compared = (
        f"{points:+.1f} points from one line alone (target within {POINTS_FROM_ONE_LINE:g}); "
        f"with the simulated drives' lateness aside, {result.share_drives_aside:.1%} of what "
        f"the wire and the drives allowed, {result.points_from_one_line_drives_aside:+.1f} "
        "points"
        if not math.isnan(points)  # the reference ran
        else "one line alone not measured"
    )
    return (
        f"{head}each line at {result.utilisation:.1%} of the wire maximum (worst line "
        f"{min(result.line_shares):.1%}), {compared}; gateway CPU {result.cpu_share:.0%} of a "
        f"core (target below 100 %; {result.cpu_per_transaction_us:.0f} us per transaction); "
        f"RSS {result.rss_mb:.1f} MiB (peak {result.peak_rss_mb:.1f}); waiting for a core "
        f"{result.run_queue_s / result.elapsed_s:.0%} of the time (the simulated drives "
        f"{result.simulator_run_queue_s / result.elapsed_s:.0%}); {gaps}; the simulated "
        f"drives answered {result.drive_late_us(0.5):.0f} us late at the median "
        f"(p90 {result.drive_late_us(0.9):.0f} us) and heard "
        f"{result.heard_gap_us(0.5):.0f} us beyond t3.5 before each request "
        f"(each line's drives spun at most {case.drive_spin_us:g} us before a reply, "
        f"one line's {WAKE_EARLY_S * 1e6:g} us shared among {case.lines})"
    )


def scada_sentence(polled: CaseResult, alone: CaseResult | None) -> str:
    """What the poller costs the SCADA's reads: their latency with it against without it."""
    with_it = f"{polled.latency_ms(0.5):.1f}/{polled.latency_ms(0.99):.1f} ms"
    head = f"{polled.case.baudrate} baud, {polled.case.name}: the readers' p50/p99 {with_it}"
    if alone is None:
        return f"{head} (without the poller: not measured)"
    p50 = polled.latency_ms(0.5) / alone.latency_ms(0.5)
    p99 = polled.latency_ms(0.99) / alone.latency_ms(0.99)
    return (
        f"{head}, without the poller {alone.latency_ms(0.5):.1f}/{alone.latency_ms(0.99):.1f} ms: "
        f"{p50:.2f}x at p50 (target <= 1.1x), {p99:.2f}x at p99 (target <= 1.2x); "
        f"the bus carried {polled.bus_per_s:.1f} transactions/s with the poller, "
        f"{polled.client_per_s:.1f} of them the readers'"
    )


OPCUA_P99_WITHIN = 0.10
"""The issue's target: the Modbus-TCP readers' p99 within 10 % of the case without OPC UA."""


def opcua_sentence(with_it: CaseResult, without: CaseResult | None) -> str:
    """What OPC UA's sessions cost: the gateway's CPU and memory, and the readers' p99."""
    case = with_it.case
    items, drives = with_it.opcua.get("items", 0), max(case.drives * case.lines, 1)
    head = (
        f"{case.baudrate} baud, {case.name}: {case.opcua} sessions each subscribed to {items} "
        f"values ({items // drives} per drive, {with_it.opcua.get('polled', 0) // drives} of "
        "them polled; 1 s publishing), "
        f"{with_it.opcua.get('notifications', 0)} notifications; the gateway's CPU "
        f"{with_it.cpu_share:.1%} of a core, RSS {with_it.rss_mb:.1f} MiB, the readers' p99 "
        f"{with_it.latency_ms(0.99):.1f} ms"
    )
    if without is None:
        return f"{head} (without OPC UA: not measured)"
    p99 = with_it.latency_ms(0.99) / without.latency_ms(0.99) - 1
    return (
        f"{head}; without OPC UA {without.cpu_share:.1%}, {without.rss_mb:.1f} MiB, "
        f"{without.latency_ms(0.99):.1f} ms: OPC UA adds "
        f"{with_it.cpu_share - without.cpu_share:+.1%} of a core "
        f"({1000 * (with_it.cpu_share - without.cpu_share):+.0f} ms of CPU per second) and "
        f"{with_it.rss_mb - without.rss_mb:+.1f} MiB, p99 {p99:+.0%} "
        f"(target within {OPCUA_P99_WITHIN:.0%})"
    )
