"""`bench --page PATH`: a run written as a Markdown page (the documentation site's Benchmark page
includes it), so the published figures are a run's, with its date and machine, not a diary.

The page says when, on what (processor, cores, memory, system, Python, event loop, priority,
the load the machine had besides), with which command and which version of the gateway, then
the targets' sentences and the whole table as the terminal shows it.
"""

from __future__ import annotations

import os
import platform
import shlex
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

from gateway.instruments.bench.cases import CaseResult
from gateway.instruments.bench.processes import processors
from gateway.instruments.bench.report import format_row, header, host_sentence, row, summary
from gateway.version import describe_version

WRITTEN_BY = "<!-- written by invt-gateway bench --page: run it again to replace this page -->"
"""The page's first line: what made it, for whoever opens the file to edit it by hand."""


@dataclass(frozen=True)
class Machine:
    """What the figures were measured on, as a reader compares them with their own."""

    processor: str
    cores: int
    memory_gib: float
    system: str
    python: str
    load_before: float
    """The 1-minute load average when the run started: other work on the machine."""

    @classmethod
    def here(cls) -> Machine:
        return cls(
            processor=_processor(),
            cores=processors(),
            memory_gib=_memory_gib(),
            system=f"{platform.system()} {platform.release()} ({platform.machine()})",
            python=f"{platform.python_implementation()} {platform.python_version()}",
            load_before=os.getloadavg()[0],
        )


def _processor() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text(encoding="utf-8").splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def _memory_gib() -> float:
    try:
        for line in Path("/proc/meminfo").read_text(encoding="utf-8").splitlines():
            if line.startswith("MemTotal:"):
                return int(line.split()[1]) / 2**20
    except OSError:
        pass
    return 0.0


def markdown(
    results: Sequence[CaseResult],
    machine: Machine,
    started: datetime,
    arguments: Sequence[str],
    event_loop: str,
    priority: str,
) -> str:
    """The page: the run's facts, the targets met or missed in words, every case's row."""
    seconds = (datetime.now(UTC) - started).total_seconds()
    took = f"{seconds / 60:.0f} min" if seconds >= 120 else f"{seconds:.0f} s"
    command = shlex.join(["invt-gateway", "bench", *arguments])
    facts = [
        ("run", f"{started:%Y-%m-%d %H:%M} UTC, {took}"),
        ("command", f"`{command}`"),
        ("gateway", f"invt-gateway {describe_version()}, on {event_loop}, {priority}"),
        ("processor", f"{machine.processor}, {machine.cores} cores"),
        ("memory", f"{machine.memory_gib:.1f} GiB"),
        ("system", f"{machine.system}, {machine.python}"),
        (
            "other load",
            f"1-minute load average {machine.load_before:.1f} at the start, "
            f"{os.getloadavg()[0]:.1f} at the end, the run's own processes included",
        ),
        ("host", host_sentence(results)),
    ]
    lines = [WRITTEN_BY, ""]
    if machine.load_before >= machine.cores / 2:
        lines += [
            '!!! warning "The machine was busy"',
            f"    Its load average was {machine.load_before:.1f} on {machine.cores} cores when the "
            "run started: other work took the cores from the gateway, the simulated drives and "
            "the clients, so these figures are below what a quiet machine gives.",
            "",
        ]
    lines += ["| | |", "|---|---|"]
    lines += [f"| {name} | {_cell(value)} |" for name, value in facts]
    lines += ["", "Against the targets:", ""]
    lines += [f"- {sentence}" for sentence in summary(list(results))]
    lines += lines_table(results)
    lines += ["", "Every case:", "", "```text", header()]
    lines += [format_row(row(result)) for result in results]
    lines += ["```", ""]
    return "\n".join(lines)


def lines_table(results: Sequence[CaseResult]) -> list[str]:
    """The lines cases side by side, as the targets read them (nothing without them)."""
    chosen = [r for r in results if r.case.many_lines]
    if not chosen:
        return []
    lines = [
        "",
        "Many lines in one gateway process (each line: 4 drives, 8 clients):",
        "",
        "| lines | drives | each line, of the wire maximum | worst line | vs 1 line, points "
        "| gateway CPU, of one core | gateway waiting for a core | RSS MiB | t3.5 violations |",
        "|---:|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in sorted(chosen, key=lambda r: (r.case.fast, r.case.lines)):
        drives = "fast" if r.case.fast else "5 ms"
        versus = "" if r.case.lines == 1 else f"{r.points_from_one_line:+.1f}"
        lines.append(
            f"| {r.case.lines} | {drives} | {r.utilisation:.1%} | {min(r.line_shares):.1%} "
            f"| {versus} | {r.cpu_share:.0%} | {r.run_queue_s / r.elapsed_s:.0%} | {r.rss_mb:.1f} "
            f"| {r.gap_violations} |"
        )
    return lines


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def write_page(path: Path, text: str) -> None:
    """Replaced whole (a temporary file renamed over it): a build never reads half a page."""
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(path.name + ".partial")
    partial.write_text(text, encoding="utf-8")
    partial.replace(path)
