"""`invt-gateway stress`: line faults, a killed gateway, an unplugged port and a restarted broker,
for a given time, against real subprocesses; a table of what the clients saw.

    invt-gateway stress --duration 600 --fault-rate 0.05

Exit 0 when it passed (no wrong value, errors below 0.1 % outside the outages, every outage
recovered, memory not grown), 1 when not.

    invt-gateway stress --cluster [--duration 120]

Three gateways of 16 simulated drives on a three-node NATS cluster (Debian's nats-server), a
dashboard with a persistent QoS 1 session, set-points sent all along; the node each gateway uses
is SIGKILLed in turn (and started again), one gateway is SIGKILLed and restarted. Exit 0 when
every stored event reached the dashboard, every drive's retained state was new through every
live node within 5 s of a change, no command ran twice and every gateway came back; 1 when not.

    invt-gateway stress --line-truth [--duration 900] [--seed 1]

Four drives on one line at the bus's defaults: a share of each one's replies late by a random
0-1000 ms, a share of its requests dropped, one of them stalled 0.4-3 s every few seconds, drives
3 and 4 silent to 08H (libmodbus devices); clients write and read back values they know. Exit 0
when no value was wrong and every drive answered right within 1 s of each stall's end.

    invt-gateway stress --history [--days 90] [--queries 10] [--duration 30]

The store filled with DAYS of history of two drives (a point a minute), then Modbus-TCP reads
for DURATION s unloaded and DURATION s with QUERIES console clients charting the whole window
at once. Exit 0 when RSS stayed within 50 MB of idle, the Modbus-TCP p99 within 20 % of the
unloaded one, and every history query was answered (200, or 503 past the console's bound).

    invt-gateway stress --opcua-fuzz N [--duration 10] [--seed 1]

N random and malformed OPC UA messages (random bytes, bad Hellos, oversized and cut-short
messages, garbage on an open channel) to a gateway's OPC UA endpoint while Modbus-TCP clients
read; DURATION s of reads without it first. Exit 0 when the Modbus-TCP p99 under the fuzz is
within 20 % of the one without, no read failed, a well-formed Hello is answered after it and
the gateway logged no traceback or error; 1 when not.

    invt-gateway stress --soak HOURS [--tracemalloc DIR]

HOURS of a plant's traffic, compressed, against one gateway: Modbus-TCP clients writing and
reading back, MQTT commands, a console viewer (events, CSV, history, logins), scrapes; every
ten minutes a drive trips and is reset, a drive stalls, the broker is stopped for 20 s, the
store's disk is full for a minute (as root). A line per sample: RSS, open files, CPU per
transaction. Exit 0 when no call failed that a fault doesn't explain and RSS grew at most
1 MB an hour after the warm-up; 1 when not. --tracemalloc DIR: the gateway traces its
allocations and writes snapshots to DIR; the lines that grew most are printed.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
from collections.abc import Callable, Coroutine
from pathlib import Path
from typing import Any, TypeVar

from gateway.exit_codes import EXIT_FAILURE, EXIT_OK
from gateway.instruments.stop_on_terminate import stop_on_terminate
from gateway.progress import Progress

BAUDRATES = (9600, 19200, 38400, 57600, 115200)
DEFAULT_DURATION_S = 60.0
DEFAULT_CLUSTER_DURATION_S = 120.0
DEFAULT_HISTORY_PHASE_S = 30.0
DEFAULT_OPCUA_FUZZ_PHASE_S = 10.0
MAX_CLIENTS = 12

Result = TypeVar("Result")


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "stress",
        help="run hostile conditions (line faults, kills, unplugging) and check every answer",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--duration",
        type=_positive,
        default=None,
        metavar="S",
        help=f"seconds under load (default {DEFAULT_DURATION_S:g}; with --cluster "
        f"{DEFAULT_CLUSTER_DURATION_S:g}: the kills come one after another, so a short run "
        "lasts as long as they take)",
    )
    parser.add_argument(
        "--cluster",
        action="store_true",
        help="gateways on a three-node NATS cluster whose nodes and one gateway are SIGKILLed "
        "(needs nats-server); the line-fault and Modbus-TCP options don't apply",
    )
    parser.add_argument(
        "--line-truth",
        action="store_true",
        help="late, dropping, stalling drives (two without 08H) on one line, every value checked "
        "(the line-fault and outage options don't apply)",
    )
    parser.add_argument(
        "--history",
        action="store_true",
        help="months of history kept, concurrent charts of all of it while SCADA reads: RSS "
        "and Modbus-TCP p99 against unloaded (--duration: each phase's seconds, default 30)",
    )
    parser.add_argument(
        "--days", type=_positive, default=90.0, help="with --history (default %(default)g)"
    )
    parser.add_argument(
        "--queries", type=int, default=10, help="with --history (default %(default)d)"
    )
    parser.add_argument(
        "--opcua-fuzz",
        type=int,
        default=None,
        metavar="N",
        help="N random and malformed messages to the OPC UA endpoint while Modbus-TCP is read "
        "(--duration: the seconds read without it first, default 10)",
    )
    parser.add_argument(
        "--soak",
        type=_positive,
        default=None,
        metavar="HOURS",
        help="hours of compressed plant traffic with trips, stalls, broker and disk outages; "
        "memory, open files and CPU per transaction sampled (the other options don't apply)",
    )
    parser.add_argument(
        "--tracemalloc",
        type=Path,
        default=None,
        metavar="DIR",
        help="with --soak: the gateway traces its allocations (slower) and writes snapshots "
        "to DIR after the warm-up and at the end; the lines that grew most are printed",
    )
    parser.add_argument(
        "--fault-rate",
        type=_rate,
        default=0.05,
        metavar="RATE",
        help="share of the drives' replies spoilt on the line (default %(default)g)",
    )
    parser.add_argument(
        "--clients",
        type=_clients,
        default=8,
        metavar="N",
        help="Modbus-TCP clients, each writing and reading back its own parameters: 1..12 "
        "(3 parameter blocks on each of the 4 drives; default %(default)d)",
    )
    parser.add_argument(
        "--baud", type=int, default=115200, choices=BAUDRATES, help="(default %(default)d)"
    )
    parser.add_argument(
        "--seed",
        type=int,
        default=1,
        help="the same seed spoils the same replies (default %(default)d)",
    )
    parser.add_argument(
        "--late-ms",
        type=_late_ms,
        default=None,
        metavar="MS|FROM-TO",
        help="how late a 'late' reply comes, or a range to draw from (0-1000: a drive busy "
        "writing its EEPROM). Beyond the response timeout and drain (200 ms) the errors are "
        "expected and only wrong values are judged (default 100: inside the drain)",
    )
    parser.add_argument(
        "--slow-drive-ms",
        type=_late_ms,
        default=None,
        metavar="MS|FROM-TO",
        help="drive 1 answers every request this late, or late by a delay drawn from the range "
        "for each reply (0-1000: slower than the response timeout at random); only wrong "
        "values are judged then",
    )
    parser.add_argument(
        "--json", action="store_true", help="one JSON document instead of the table"
    )
    parser.set_defaults(handler=handle)


def handle(args: argparse.Namespace) -> int:
    stop_on_terminate()  # a run ended by SIGTERM stops its gateway, drives and broker too
    if args.cluster:
        return handle_cluster(args)
    if args.line_truth:
        return handle_line_truth(args)
    if args.soak is not None:
        return handle_soak(args)
    if args.history:
        return handle_history(args)
    if args.opcua_fuzz is not None:
        return handle_opcua_fuzz(args)
    from gateway.instruments.stress.report import document, problems, table
    from gateway.instruments.stress.scenario import StressSettings, run_stress

    settings = StressSettings(
        duration_s=DEFAULT_DURATION_S if args.duration is None else args.duration,
        fault_rate=args.fault_rate,
        clients=args.clients,
        baudrate=args.baud,
        seed=args.seed,
        slow_drive_ms=args.slow_drive_ms,
        **({} if args.late_ms is None else {"late_ms": args.late_ms}),
    )

    # The run is its duration; starting and stopping the processes add a few seconds.
    return _run_load(
        "stress",
        settings.duration_s,
        lambda note: run_stress(settings, note),
        table,
        problems,
        lambda result: {"gateway": result.gateway_log},
        document if args.json else None,
    )


def handle_line_truth(args: argparse.Namespace) -> int:
    from gateway.instruments.stress.line_truth import line_truth_table, run_line_truth

    duration_s = DEFAULT_DURATION_S if args.duration is None else args.duration
    return _run_load(
        "stress --line-truth",
        duration_s,
        lambda note: run_line_truth(duration_s, args.seed, note),
        line_truth_table,
        lambda result: result.problems(),
        lambda result: {"gateway": result.gateway_log},
    )


def handle_soak(args: argparse.Namespace) -> int:
    from gateway.instruments.stress.soak import SoakSettings, run_soak
    from gateway.instruments.stress.soak_report import problems, table

    settings = SoakSettings(args.soak, args.seed, args.tracemalloc)
    return _run_load(
        "stress --soak",
        settings.duration_s,
        lambda note: run_soak(settings, note),
        table,
        problems,
        lambda result: {"gateway": result.gateway_log},
    )


def handle_history(args: argparse.Namespace) -> int:
    from gateway.instruments.stress.history_load import (
        HistoryLoadSettings,
        problems,
        run_history_load,
        table,
    )

    phase_s = DEFAULT_HISTORY_PHASE_S if args.duration is None else args.duration
    settings = HistoryLoadSettings(args.days, args.queries, phase_s)
    return _run_load(
        "stress --history",
        2 * phase_s,
        lambda _note: run_history_load(settings),
        table,
        problems,
        lambda result: {"gateway": result.gateway_log},
    )


def handle_opcua_fuzz(args: argparse.Namespace) -> int:
    from gateway.instruments.stress.opcua_fuzz_load import (
        OpcUaFuzzSettings,
        problems,
        run_opcua_fuzz,
        table,
    )

    phase_s = DEFAULT_OPCUA_FUZZ_PHASE_S if args.duration is None else args.duration
    settings = OpcUaFuzzSettings(args.opcua_fuzz, phase_s, args.seed)
    return _run_load(
        "stress --opcua-fuzz",
        2 * phase_s,
        lambda _note: run_opcua_fuzz(settings),
        table,
        problems,
        lambda result: {"gateway": result.gateway_log},
    )


def handle_cluster(args: argparse.Namespace) -> int:
    from gateway.instruments.stress.cluster import ClusterSettings, run_cluster_stress
    from gateway.instruments.stress.cluster_report import document, problems, table

    duration = DEFAULT_CLUSTER_DURATION_S if args.duration is None else args.duration
    settings = ClusterSettings(duration_s=duration)
    return _run_load(
        "stress --cluster",
        settings.duration_s,
        lambda note: run_cluster_stress(settings, note),
        table,
        problems,
        lambda result: {f"gateway {name}": lines for name, lines in result.logs.items()},
        document if args.json else None,
    )


def _run_load(
    title: str,
    planned_s: float,
    run: Callable[[Callable[[str], None]], Coroutine[Any, Any, Result]],
    table: Callable[[Result], str],
    problems: Callable[[Result], object],
    logs: Callable[[Result], dict[str, str]],
    document: Callable[[Result], object] | None = None,
) -> int:
    """Every kind of stress run the same way: `run` (given the progress line's `note`) under
    a progress line planned for `planned_s`, then its table (or JSON `document`), and exit 1
    with each gateway's last log lines when it found `problems`."""
    with Progress(title, planned_s, sys.stderr) as overall:
        try:
            result = asyncio.run(run(overall.note))
        except (RuntimeError, ValueError, OSError) as exc:
            overall.print(f"invt-gateway {title}: {exc}", sys.stderr)
            return EXIT_FAILURE
    if document is not None:
        print(json.dumps(document(result), indent=2), flush=True)
    else:
        print(table(result), flush=True)
    if problems(result):
        for name, lines in logs(result).items():
            if lines:
                print(f"{name}'s last log lines:\n{lines}", file=sys.stderr)
        return EXIT_FAILURE
    return EXIT_OK


def _late_ms(text: str) -> tuple[float, float]:
    from gateway.instruments.simulator.line_faults import late_range

    try:
        return late_range(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _positive(text: str) -> float:
    value = float(text)
    if value <= 0:
        raise argparse.ArgumentTypeError("must be more than 0")
    return value


def _clients(text: str) -> int:
    value = int(text)
    if not 1 <= value <= MAX_CLIENTS:
        raise argparse.ArgumentTypeError(f"{value} is outside 1..{MAX_CLIENTS}")
    return value


def _rate(text: str) -> float:
    value = float(text)
    if not 0.0 <= value < 1.0:
        raise argparse.ArgumentTypeError(f"{value} is outside 0..1")
    return value
