"""`invt-gateway bench`: the line's physical limit against what the gateway gets out of it."""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from datetime import UTC, datetime
from pathlib import Path

from gateway import ENGINE_ROOM
from gateway.errors import ConfigError
from gateway.event_loop import choose_event_loop
from gateway.exit_codes import EXIT_FAILURE, EXIT_OK, EXIT_USAGE
from gateway.instruments.stop_on_terminate import stop_on_terminate
from gateway.progress import Progress

BAUDRATES = (9600, 19200, 115200)
RELAY_MS = 0.25
"""The relay cases' delay each way by default: a serial device server's, or a USB adapter's
with its latency timer at its lowest (the simulator's `--relay-ms`)."""
CASE_START_S = 1.0
"""About what starting and stopping a case's processes takes here, for the first estimate of
the end (later ones go by the pace of the cases done)."""
TRANSACTIONS = (100, 400)
"""`--instructions`: 300 transactions apart, enough for start-up's own variation (a few hundred
thousand instructions in 1.7 billion) to be lost in the difference."""
VALGRIND_START_S = 30.0
"""About what one gateway's start-up and stop under callgrind take here, for the estimate."""
VALGRIND_TRANSACTION_S = 0.04
"""About a transaction under callgrind: the 32 ms gap at 1200 baud and the work after it."""


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
        "'lines' (4, 8, 16 and 32 buses in one process, 5 ms and fast drives, each against "
        "its 1-line reference, which a chosen lines case brings along; one simulator process "
        "serves all the lines), 'flood' (readers while one client pipelines writes or "
        "broadcasts) and 'opcua' (32 polled drives on 4 lines with 8 Modbus-TCP readers, "
        "without and with 5 OPC UA sessions subscribed to every value; needs the opcua extra)",
    )
    parser.add_argument(
        "--relay-ms",
        type=relay_ms,
        default=RELAY_MS,
        metavar="MS",
        help="the relay cases' delay each way between the gateway's port and the simulated "
        "drives' wire, as a USB adapter's timer or a serial device server adds it; their wire "
        "maximum counts it (default %(default)g; 0 leaves those cases out)",
    )
    parser.add_argument(
        "--json", action="store_true", help="one JSON document instead of the table"
    )
    parser.add_argument(
        "--page",
        metavar="PATH",
        type=Path,
        help="also write the run as a Markdown page to PATH (date, machine, command, version, "
        "the targets, every case): the documentation site's Benchmark page includes "
        "docs/bench/run.md",
    )
    parser.add_argument(
        "--instructions",
        action="store_true",
        help="instead of the cases: count the user-space instructions the gateway process "
        "executes per bus transaction (one client, sequential 2-word reads, 1200 baud, no wire "
        "delay), with valgrind's callgrind (needs valgrind; about a minute a run). "
        "Repeatable to ~0.5 %% whatever else the machine does, unlike CPU time: for comparing "
        "two versions of the code, not a cost in time (no kernel work, no waits). --runs "
        "repeats it; --baud, --case, --duration and --warmup don't apply",
    )
    parser.add_argument(
        "--transactions",
        type=int,
        nargs=2,
        default=list(TRANSACTIONS),
        metavar=("LOW", "HIGH"),
        help="with --instructions: the reads of its short and its long run; start-up and "
        f"shutdown cancel out of the difference (default {TRANSACTIONS[0]} {TRANSACTIONS[1]})",
    )
    parser.add_argument(
        "--gateway-from",
        metavar="FOLDER",
        help="with --instructions: run the gateway of another checkout of the source (its top "
        "folder), measured by this bench with this simulator, so that two versions compare "
        "alike, even one from before --instructions existed",
    )
    parser.set_defaults(handler=handle)


def handle(args: argparse.Namespace) -> int:
    stop_on_terminate()  # a bench ended by SIGTERM stops its gateway and drives too
    if args.instructions:
        if args.page is not None:
            print(
                "invt-gateway bench: --page writes the cases' run, not --instructions",
                file=sys.stderr,
            )
            return EXIT_USAGE
        return count_instructions(args)
    from gateway.instruments.bench import page
    from gateway.instruments.bench.cases import (
        CaseResult,
        extra_cases,
        matrix,
        run_case,
        with_references,
    )
    from gateway.instruments.bench.processes import gateway_niceness
    from gateway.instruments.bench.report import (
        format_row,
        header,
        host_sentence,
        row,
        summary,
    )

    baudrates = tuple(args.baud or BAUDRATES)
    cases = matrix(baudrates, args.relay_ms)
    if args.case:
        cases = [c for c in cases + extra_cases(baudrates) if args.case in c.name]
        cases = with_references(cases)  # a lines case's row compares it with one line
    results: list[CaseResult] = []
    one_line: dict[tuple[int, bool], CaseResult] = {}  # the 1-line references, by (baud, fast)
    loop = gateway_event_loop()
    if loop is None:
        return EXIT_USAGE
    started, machine = datetime.now(UTC), page.Machine.here()
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
            if case.many_lines:
                if case.lines == 1:
                    one_line[case.baudrate, case.fast] = result
                reference = one_line.get((case.baudrate, case.fast))
                if reference is not None:
                    result.single_line_share = reference.utilisation
                    result.single_line_share_drives_aside = reference.share_drives_aside
            results.append(result)
            if not args.json:
                progress.print(format_row(row(result)), sys.stdout)
    if args.json:
        json.dump(
            {
                "event_loop": loop,
                "engine_room": ENGINE_ROOM,
                "priority": gateway_niceness(),
                "host": host_sentence(results),
                "cases": [row(r) for r in results],
                "summary": summary(results),
            },
            sys.stdout,
            indent=2,
        )
        print()
    else:
        print()
        print(f"the gateway ran on {loop}, {gateway_niceness()}")
        print(f"its engine room: {ENGINE_ROOM}")
        print(host_sentence(results))
        for line in summary(results):
            print(line)
    if args.page is not None:
        text = page.markdown(
            results, machine, started, page_arguments(args), loop, gateway_niceness()
        )
        page.write_page(args.page, text)
        print(f"invt-gateway bench: wrote {args.page}", file=sys.stderr)
    return EXIT_OK


def page_arguments(args: argparse.Namespace) -> list[str]:
    """The options this run was given, as the page shows its command."""
    given = [f"--baud={baud}" for baud in args.baud or ()]
    given += [f"--duration={args.duration:g}", f"--warmup={args.warmup:g}", f"--runs={args.runs}"]
    given += [f"--case={args.case}"] if args.case else []
    given += [f"--relay-ms={args.relay_ms:g}"] if args.relay_ms != RELAY_MS else []
    return [*given, f"--page={args.page}"]


def relay_ms(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"relay delay {text!r} is no number of ms") from None
    if not 0.0 <= value <= 100.0:
        raise argparse.ArgumentTypeError(f"relay delay {value:g} ms is outside 0..100")
    return value


def gateway_event_loop() -> str | None:
    """The event loop the gateway processes will run on: they inherit this environment, so
    they choose as this does. None (and why, on stderr) if the choice is refused."""
    try:
        return choose_event_loop().describe()
    except ConfigError as exc:
        print(f"invt-gateway bench: {exc}", file=sys.stderr)
        return None


def count_instructions(args: argparse.Namespace) -> int:
    from gateway.errors import InstructionCountError
    from gateway.instruments.bench import instructions

    low, high = args.transactions
    if args.baud or args.case:
        print("invt-gateway bench: --instructions has its own case and baud rate", file=sys.stderr)
        return EXIT_USAGE
    source = args.gateway_from
    if source is not None and not (Path(source) / "gateway" / "__main__.py").is_file():
        print(f"invt-gateway bench: {source} is no checkout of invt-gateway", file=sys.stderr)
        return EXIT_USAGE
    if not 0 <= low < high or args.runs < 1:
        print("invt-gateway bench: needs 0 <= LOW < HIGH and --runs >= 1", file=sys.stderr)
        return EXIT_USAGE
    valgrind = shutil.which("valgrind")
    if valgrind is None:
        print(instructions.MISSING, file=sys.stderr)
        return EXIT_FAILURE
    loop = gateway_event_loop()
    if loop is None:
        return EXIT_USAGE
    pinning = instructions.fixed_addresses()
    if not pinning:
        print(instructions.UNPINNED, file=sys.stderr)
    plan = 2 * VALGRIND_START_S + (low + high) * VALGRIND_TRANSACTION_S
    counts = []
    with Progress("bench", plan * args.runs, sys.stderr) as progress:
        for number in range(args.runs):
            progress.step(f"run {number + 1} of {args.runs} ({low} and {high} reads, callgrind)")
            try:
                counts.append(instructions.measure(valgrind, low, high, pinning, source))
            # A wrong reply or no count (InstructionCountError); a process that didn't start.
            except (InstructionCountError, RuntimeError) as error:
                progress.print(f"invt-gateway bench --instructions: {error}", sys.stderr)
                return EXIT_FAILURE
            progress.advance(plan)
    engine_room = instructions.engine_room(source)
    if args.json:
        json.dump(
            {**instructions.as_json(counts), "engine_room": engine_room}, sys.stdout, indent=2
        )
        print()
    else:
        if source is None:
            print(f"the gateway ran on {loop}")
        print(f"its engine room: {engine_room}")
        for line in instructions.report(counts):
            print(line)
    return EXIT_OK
