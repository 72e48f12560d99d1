"""`invt-gateway bench`: the line's physical limit against what the gateway gets out of it."""

from __future__ import annotations

import argparse
import json
import sys

from gateway.cli import EXIT_OK
from gateway.progress import Progress

BAUDRATES = (9600, 19200, 115200)
CASE_START_S = 1.0
"""About what starting and stopping a case's processes takes here, for the first estimate of
the end (later ones go by the pace of the cases done)."""


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "bench",
        help="measure throughput, latency, CPU and memory against the wire's theoretical maximum",
        description="Starts simulated drives with wire-time emulation on a virtual line, the "
        "gateway and Modbus-TCP clients as separate processes, and prints one row per case.",
    )
    parser.add_argument(
        "--baud",
        type=int,
        action="append",
        choices=BAUDRATES,
        help="repeatable (default: all of " + ", ".join(map(str, BAUDRATES)) + ")",
    )
    parser.add_argument(
        "--duration",
        type=float,
        default=4.0,
        help="seconds measured per case (default %(default)g)",
    )
    parser.add_argument(
        "--warmup",
        type=float,
        default=1.5,
        help="seconds before measuring (default %(default)g; at least 3 with a dead drive)",
    )
    parser.add_argument(
        "--runs",
        type=int,
        default=1,
        help="runs per case; the median is shown (default %(default)d)",
    )
    parser.add_argument(
        "--case",
        help="only cases whose name contains this text (default: the main matrix, about 4 "
        "minutes at the default duration). Also selects the cases left out by default: "
        "'lines' (4, 8 and 16 buses in one process, 5 ms and fast drives; 16 simulator "
        "processes share the machine) and 'flood' (readers while one client pipelines writes or "
        "broadcasts)",
    )
    parser.add_argument(
        "--json", action="store_true", help="one JSON document instead of the table"
    )
    parser.set_defaults(handler=handle)


def handle(args: argparse.Namespace) -> int:
    from gateway.instruments.bench.cases import CaseResult, extra_cases, matrix, run_case
    from gateway.instruments.bench.report import format_row, header, row, summary

    baudrates = tuple(args.baud or BAUDRATES)
    cases = matrix(baudrates)
    if args.case:
        cases = [c for c in cases + extra_cases(baudrates) if args.case in c.name]
    results: list[CaseResult] = []
    if not args.json:
        print(header(), flush=True)
    # Isolating a dead drive takes a few timeouts: measure the steady state after it.
    warmups = [max(args.warmup, 3.0) if case.dead else args.warmup for case in cases]
    planned = [(args.duration + warmup + CASE_START_S) * args.runs for warmup in warmups]
    with Progress("bench", sum(planned), sys.stderr) as progress:
        for number, (case, warmup, plan) in enumerate(zip(cases, warmups, planned, strict=True)):
            progress.step(f"case {number + 1} of {len(cases)} ({case.name}, {case.baudrate} baud)")
            runs = [run_case(case, args.duration, warmup) for _ in range(args.runs)]
            progress.advance(plan)
            result = sorted(runs, key=lambda r: r.client_per_s)[len(runs) // 2]
            results.append(result)
            if not args.json:
                progress.print(format_row(row(result)), sys.stdout)
    if args.json:
        json.dump(
            {"cases": [row(r) for r in results], "summary": summary(results)}, sys.stdout, indent=2
        )
        print()
    else:
        print()
        for line in summary(results):
            print(line)
    return EXIT_OK
