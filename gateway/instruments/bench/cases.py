"""The benchmark's cases and how one is run."""

from __future__ import annotations

import asyncio
import contextlib
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gateway.bus.gap_excess import quantile
from gateway.collector import collector_paused
from gateway.event_loop import choose_event_loop
from gateway.event_loop import run as run_on_loop
from gateway.instruments.bench.load import LoadResult, flood, run_clients
from gateway.instruments.bench.opcua import opcua_clients, run_slowly, server_section
from gateway.instruments.bench.prepare import SET_POINT, prepare_reads
from gateway.instruments.bench.processes import (
    GatewayProcess,
    SimulatorLine,
    free_port,
    gateway,
    host_steal_s,
    processors,
    simulator,
    wait_listening,
)
from gateway.instruments.bench.scrape import excess_gap_buckets
from gateway.instruments.bench.wire import WireBudget, read_budget
from gateway.instruments.simulator.line import WAKE_EARLY_S
from gateway.modbus.timing import CharacterFormat

RESPONSE_DELAY_MS = 5.0  # INVT P14.03's default
FAST_TURNAROUND_S = 0.001
"""A fast drive (P14.03 = 0) answers about 1 ms after the t3.5 that ends the request."""
LINE_COUNTS = (4, 8, 16, 32)  # the multi-line cases, at the fastest baud rate
LINES_PER_SIMULATOR = 32
"""Lines one simulator process serves (from one thread): one process for every lines case,
so that the harness is not what limits the gateway. One process per line took more of the
cores than the gateway measured, and at 32 lines four processes of eight lines did no better
than one (the one thread used under half a core)."""
SCRAPE_SETTLE_S = 0.5
"""Between the gateway's first /metrics scrape of a case and the start of its measured time."""
FLOOD_WINDOW = 8
"""Requests the flooding client keeps in flight (below max_queued_writes_per_client's 16)."""
ADAPTER_BAUD = 19200  # where the real-adapter cases run: the factory setting of P14.01


OPCUA = "opcua:"
OPCUA_SESSIONS = 5
SCADA_BAUDS = (19200, 115200)
"""Where the SCADA-with-poller cases run: P14.01's factory setting and the fastest."""
SCADA_ALONE = "scada: 8 readers alone"
SCADA_POLLED = "scada: 8 readers + poller"
"""The same readers while the poller polls every drive at its profile's default plan: what
the polls cost a SCADA's reads, against `SCADA_ALONE`."""


def relay_case_name(relay_ms: float) -> str:
    return f"2w 8c fast drives, relay {relay_ms:g} ms"


def matrix(baudrates: tuple[int, ...], relay_ms: float = 0.0) -> list[Case]:
    """Every case the issue asks for, per baud rate; then the cache and the scale cases.
    `relay_ms`: the relay cases' delay each way (0: none)."""
    cases = []
    for baud in baudrates:
        for words in (2, 16):
            for clients in (1, 8, 32):
                cases.append(Case(f"{words}w {clients}c", baud, words, clients))
        # Fast drives: the gateway's own share is no longer hidden in a 5 ms response delay.
        cases.append(Case("2w 8c fast drives", baud, 2, 8, fast=True))
        cases.append(Case("16w 8c fast drives", baud, 16, 8, fast=True))
        # A relay between the gateway's port and the wire, as the plant's path has one: the
        # wire maximum counts its delay each way, so what is lost beyond it is the gateway's.
        if relay_ms:
            cases.append(Case(relay_case_name(relay_ms), baud, 2, 8, fast=True, relay_ms=relay_ms))
        cases.append(Case("2w 8c same registers", baud, 2, 8, same_registers=True))
        cases.append(Case("2w 8c one dead of 4", baud, 2, 8, dead=1))
        if baud in SCADA_BAUDS:
            cases.append(Case(SCADA_ALONE, baud, 2, 8))
            cases.append(Case(SCADA_POLLED, baud, 2, 8, polled=True))
        if baud == ADAPTER_BAUD:
            # Real adapters: bursts cutting every reply, a glitch byte before every reply, an
            # echo nobody configured; the wire maximum counts what the bursts hold back.
            cases.append(Case("16w 1c bursts 40 ms", baud, 16, 1, burst_ms=40))
            cases.append(Case("2w 8c glitch FFH", baud, 2, 8, glitch=True))
            cases.append(Case("2w 8c echo, echo: false", baud, 2, 8, echo=True))
    fastest = max(baudrates)
    # No wire delay: the gateway's CPU per transaction, with nothing on the line to hide it.
    cases.append(Case("no wire delay", fastest, 2, 1, no_wire=True))
    cases.append(Case("2w 8c same regs, cache", fastest, 2, 8, same_registers=True, cache=True))
    cases.append(Case("2w 64c on 32 drives", fastest, 2, 64, drives=32))
    # The console: what it costs with nobody watching the traffic, and with a monitor open.
    # Its drives are polled (as with MQTT), so the baseline polls them the same way.
    cases.append(Case("2w 8c polled", fastest, 2, 8, polled=True))
    cases.append(Case("2w 8c polled+console", fastest, 2, 8, polled=True, console=True))
    cases.append(
        Case("2w 8c console+monitor", fastest, 2, 8, polled=True, console=True, monitor=True)
    )
    return cases


def extra_cases(baudrates: tuple[int, ...]) -> list[Case]:
    """Cases run only when `--case` names them: several lines in one process, and floods."""
    fastest = max(baudrates)
    cases = [lines_reference(fastest, fast) for fast in (False, True)]
    for lines in LINE_COUNTS:
        for fast in (False, True):
            name = f"{lines} lines, 4 drives, 8c each, {_speed(fast)}"
            cases.append(Case(name, fastest, 2, 8, lines=lines, fast=fast, many_lines=True))
    # Readers on a line flooded by one client's pipelined writes, or broadcasts: what is left
    # for them (against "2w 8c" unloaded) is the fair share at work.
    cases.append(Case("flood: 8 readers alone", fastest, 2, 8))
    cases.append(Case("flood: 8 readers + pipelined writes", fastest, 2, 8, flood="writes"))
    cases.append(Case("flood: 8 readers + pipelined broadcasts", fastest, 2, 8, flood="broadcasts"))
    # OPC UA's cost: 32 polled drives on 4 lines, 8 Modbus-TCP readers; then the same with 5
    # SCADA sessions subscribed to every value of every drive.
    for sessions in (0, OPCUA_SESSIONS):
        name = f"{OPCUA} 32 drives, 8 readers" + (f" + {sessions} OPC UA" * bool(sessions))
        cases.append(Case(name, fastest, 2, 2, 8, polled=True, fast=True, lines=4, opcua=sessions))
    return cases


def _speed(fast: bool) -> str:
    return "fast drives" if fast else "5 ms drives"


def lines_reference(baudrate: int, fast: bool) -> Case:
    """One line, as each line of the lines cases has it, served the same way: what each of
    them is compared with."""
    name = f"lines ref: 1 line, 4 drives, 8c each, {_speed(fast)}"
    return Case(name, baudrate, 2, 8, fast=fast, many_lines=True)


def with_references(cases: list[Case]) -> list[Case]:
    """`cases` with the 1-line reference of every lines case chosen, each before the first
    case it is the reference of (its figure is in their rows)."""
    chosen: list[Case] = []
    for case in cases:
        reference = lines_reference(case.baudrate, case.fast)
        if case.many_lines and case.lines > 1 and reference not in chosen:
            chosen.append(reference)
        if case not in chosen:
            chosen.append(case)
    return chosen


@dataclass(frozen=True, slots=True)
class Case:
    name: str
    baudrate: int
    words: int
    clients: int
    drives: int = 4
    same_registers: bool = False
    dead: int = 0
    cache: bool = False
    burst_ms: float = 0.0
    glitch: bool = False
    echo: bool = False
    polled: bool = False
    """Every drive polled with its profile's groups, as the console and MQTT have them polled."""
    console: bool = False
    monitor: bool = False
    """A traffic monitor open on the console for the whole case, reading every transaction."""
    fast: bool = False
    """Drives answering 1 ms after the request's t3.5 (P14.03 = 0) instead of after 5 ms."""
    lines: int = 1
    """Buses in the one gateway process, each with `drives` drives and `clients` clients."""
    many_lines: bool = False
    """One of the lines cases (their 1-line reference too): compared line for line."""
    flood: str = ""
    """"writes" or "broadcasts": one more client keeps `FLOOD_WINDOW` of them in flight."""
    relay_ms: float = 0.0
    """A relay between the gateway's port and the drives' wire, delaying every byte this long
    each way (a USB adapter's timer, a serial device server)."""
    no_wire: bool = False
    """Bytes take no time on the virtual line and the drives answer at once: what is left per
    transaction is the gap the gateway keeps, and its own work."""
    opcua: int = 0
    """OPC UA client sessions (another process) subscribed to every value of every drive."""

    @property
    def response_delay_s(self) -> float:
        if self.no_wire:
            return 0.0
        if self.fast:
            return CharacterFormat(self.baudrate, "E").t35_s + FAST_TURNAROUND_S
        return RESPONSE_DELAY_MS / 1000

    def units(self, line: int) -> list[int]:
        """The unit ids of the drives on `line` (0-based): unique across the gateway."""
        return [line * self.drives + a for a in range(1, self.drives + 1)]

    @property
    def adapter_args(self) -> list[str]:
        """`simulate` options for the adapter this case's line has."""
        args = ["--burst-ms", f"{self.burst_ms:g}"] if self.burst_ms else []
        args += ["--glitch", "FF"] if self.glitch else []
        return args + (["--echo"] if self.echo else [])

    @property
    def drive_spin_us(self) -> float:
        """How long each line's simulated drives may spin before a reply: one line's worth
        shared among the lines, so that the drives of sixteen lines don't take the cores
        the gateway is measured on (they did: 1.2 cores of the two, its worst line 92-94 %
        against 97 % with the spin shared)."""
        return WAKE_EARLY_S * 1e6 / max(self.lines, 1)

    @property
    def simulator_args(self) -> list[str]:
        args = self.adapter_args + (["--no-wire-time"] if self.no_wire else [])
        args += ["--relay-ms", f"{self.relay_ms:g}"] if self.relay_ms else []
        return [*args, "--wake-early-us", f"{self.drive_spin_us:g}"]

    def baseline(self) -> Case:
        """The same load with every drive alive."""
        return Case(f"{self.words}w {self.clients}c", self.baudrate, self.words, self.clients)

    @property
    def budget(self) -> WireBudget:
        return read_budget(
            self.baudrate,
            self.words,
            self.response_delay_s,
            burst_s=self.burst_ms / 1000,
            wire=not self.no_wire,
            relay_s=self.relay_ms / 1000,
        )


@dataclass
class CaseResult:
    case: Case
    elapsed_s: float
    load: LoadResult
    bus_transactions: int
    """On all lines together."""
    gap_violations: int
    cpu_s: float
    peak_rss_mb: float
    rss_mb: float = float("nan")
    """The gateway's resident memory (MiB) at the end of the measured time."""
    simulator_cpu_s: float = float("nan")
    """The simulated drives' processes' CPU time over the measured time, all together."""
    run_queue_s: float = float("nan")
    """How long the gateway waited for a core over the measured time, runnable but not
    running: the machine's other work (the drives, the clients, whatever else runs)."""
    simulator_run_queue_s: float = float("nan")
    """The same for the simulated drives' processes, all together."""
    host_steal_s: float = float("nan")
    """CPU time the hypervisor took from this machine's processors over the measured time
    (steal, all processors together): a host busy with other machines."""
    single_line_share: float = float("nan")
    """Lines cases: the share of the wire one line carried in their 1-line reference, when
    it ran (`with_references`)."""
    single_line_share_drives_aside: float = float("nan")
    """The same, with its drives' lateness aside (`share_drives_aside`)."""
    excess_gap: list[tuple[float, int]] = field(default_factory=list)
    """The gateway's `bus_excess_gap_seconds` buckets over the measured time, all lines."""
    line_transactions: list[int] = field(default_factory=list)
    """Per line."""
    unloaded_p99_ms: float = float("nan")
    """Flood cases: the readers' p99 in the same case without the flood."""
    drive_late: list[tuple[float, int]] = field(default_factory=list)
    """How late the simulated drives' replies went out, over the measured time, all lines:
    cumulative (upper bound, count) buckets, in seconds."""
    drive_late_s: float = 0.0
    """The simulated drives' replies' lateness summed over the measured time, all lines."""
    heard_gap: list[tuple[float, int]] = field(default_factory=list)
    opcua: dict[str, int] = field(default_factory=dict)
    """The OPC UA clients' monitored items per session and notifications seen (all)."""
    """The silence beyond t3.5 the drives heard between each reply and the next request: the
    gateway's share (`excess_gap`) plus its reading of the reply and the virtual line's relay."""

    def excess_gap_us(self, quantile_: float) -> float:
        return 1e6 * quantile(self.excess_gap, quantile_)

    def drive_late_us(self, quantile_: float) -> float:
        return 1e6 * quantile(self.drive_late, quantile_)

    def heard_gap_us(self, quantile_: float) -> float:
        return 1e6 * quantile(self.heard_gap, quantile_)

    @property
    def excess_gap_count(self) -> int:
        """How many transactions the excess gap's quantiles rest on (those the gap's end found
        waiting): below a hundred, the p99 is the slowest of them."""
        return self.excess_gap[-1][1] if self.excess_gap else 0

    @property
    def overhead_us(self) -> float:
        """Measured time per transaction on a line beyond the wire's: everything not physics."""
        per_line = self.bus_transactions / max(self.case.lines, 1)
        if not per_line:
            return float("nan")
        return 1e6 * (self.elapsed_s / per_line - self.case.budget.transaction_s)

    @property
    def line_shares(self) -> list[float]:
        """Each line's transactions over its wire maximum."""
        wire = self.case.budget.transaction_s
        return [n * wire / self.elapsed_s for n in self.line_transactions]

    @property
    def client_per_s(self) -> float:
        """Per line (the mean over the lines)."""
        return self.load.answered / self.elapsed_s / max(self.case.lines, 1)

    @property
    def bus_per_s(self) -> float:
        """Per line (the mean over the lines)."""
        return self.bus_transactions / self.elapsed_s / max(self.case.lines, 1)

    @property
    def wire_max_per_s(self) -> float:
        return self.case.budget.max_per_s

    @property
    def utilisation(self) -> float:
        """Of one line (the mean over the lines)."""
        lines = max(self.case.lines, 1)
        return self.bus_transactions * self.case.budget.transaction_s / self.elapsed_s / lines

    @property
    def share_drives_aside(self) -> float:
        """Of what the wire and the simulated drives allowed (the mean over the lines): the
        time a line waited for a reply that went out late is taken from the time it had, as a
        relay's delay is. A drive answers on its own clock on a real line; here one thread
        answers for every line's drives, on the cores the gateway uses, and at 32 lines it
        wakes tens of microseconds late where one line's spins the last 300 on the clock."""
        lines = max(self.case.lines, 1)
        available = self.elapsed_s * lines - self.drive_late_s
        return self.bus_transactions * self.case.budget.transaction_s / available

    @property
    def points_from_one_line_drives_aside(self) -> float:
        """`points_from_one_line` on `share_drives_aside`."""
        return 100 * (self.share_drives_aside - self.single_line_share_drives_aside)

    @property
    def points_from_one_line(self) -> float:
        """Lines cases: the mean line's share of the wire minus one line's alone, in percentage
        points (negative: each line carries less than one alone)."""
        return 100 * (self.utilisation - self.single_line_share)

    @property
    def cpu_per_transaction_us(self) -> float:
        return 1e6 * self.cpu_s / max(self.bus_transactions, 1)

    @property
    def cpu_per_answer_us(self) -> float:
        """Per client request answered: with coalescing, one transaction answers several."""
        return 1e6 * self.cpu_s / max(self.load.answered + self.load.dead_answers, 1)

    @property
    def cpu_share(self) -> float:
        """The gateway's CPU time over wall time: 1.0 is one core kept busy."""
        return self.cpu_s / self.elapsed_s

    @property
    def host_steal_share(self) -> float:
        """Of all this machine's processors' time: 0.02 is 2 % of every core taken away."""
        return self.host_steal_s / (self.elapsed_s * processors())

    @property
    def simulator_cpu_share(self) -> float:
        """The simulated drives' (the harness's): a line served from one thread can't have
        more than 1.0, and well below it answers on time."""
        return self.simulator_cpu_s / self.elapsed_s

    def latency_ms(self, quantile: float) -> float:
        latencies = sorted(self.load.latencies_s)
        if not latencies:
            return float("nan")
        return 1000 * latencies[min(len(latencies) - 1, int(quantile * len(latencies)))]

    @property
    def healthy_units(self) -> range:
        return range(1, self.case.drives - self.case.dead + 1)

    def per_s_of(self, units: range) -> float:
        """Correct answers per second from the drives with these unit ids."""
        return sum(self.load.answered_by_unit[u] for u in units) / self.elapsed_s


POLL_GROUPS = [  # the INVT profile's own, written out so a case without the console polls alike
    {"name": "state", "start": 0x2100, "count": 3, "interval_ms": 500},
    {"name": "running", "start": 0x3000, "count": 12, "interval_ms": 2000},
]


def gateway_config(
    case: Case,
    line_paths: list[str],
    port: int,
    console_port: int = 0,
    metrics_port: int = 0,
    folder: Path | None = None,
) -> dict[str, Any]:
    drives: list[dict[str, Any]] = [
        {
            "name": f"drive{unit}",
            "bus": f"line{line + 1}",
            "address": address,
            "unit_id": unit,
            "model": "gd350",
        }
        for line in range(len(line_paths))
        for address, unit in enumerate(case.units(line), 1)
    ]
    if case.cache:
        for drive in drives:
            drive["cache_max_age_ms"] = 1000
            drive["poll"] = [
                {"name": "bench", "start": SET_POINT, "count": case.words, "interval_ms": 200}
            ]
    if case.polled:
        for drive in drives:
            drive["poll"] = POLL_GROUPS
    # Every client of every line, the flooding client and the one that prepares the reads.
    max_connections = max(256, case.clients * case.lines + 16)
    config: dict[str, Any] = {
        "gateway_id": "bench",
        "modbus_tcp": {
            "host": "127.0.0.1",
            "port": port,
            "max_connections": max_connections,
            # All the bench's clients come from 127.0.0.1: one client address holds them all.
            "max_connections_per_client": max_connections,
        },
        "buses": [
            {"name": f"line{n}", "port": path, "baudrate": case.baudrate, "parity": "E"}
            for n, path in enumerate(line_paths, 1)
        ],
        "drives": drives,
        "logging": {"level": "warning"},
    }
    if metrics_port:
        config["metrics"] = {"enabled": True, "host": "127.0.0.1", "port": metrics_port}
    if case.opcua and folder is not None:
        config["opcua"] = server_section(folder, free_port(), config["gateway_id"])
    if case.console:
        config["console"] = {
            "enabled": True,
            "host": "127.0.0.1",
            "port": console_port,
            "anonymous_view": True,
        }
    return config


def run_case(case: Case, duration_s: float, warmup_s: float) -> CaseResult:
    dead = list(range(case.drives - case.dead + 1, case.drives + 1))
    addresses = list(range(1, case.drives + 1))  # on each line; unit ids differ per line
    delay_ms = 1000 * case.response_delay_s
    with contextlib.ExitStack() as stack:
        lines = [
            line
            for first in range(0, case.lines, LINES_PER_SIMULATOR)
            for line in stack.enter_context(
                simulator(
                    addresses,
                    case.baudrate,
                    dead,
                    delay_ms,
                    case.simulator_args,
                    min(LINES_PER_SIMULATOR, case.lines - first),
                )
            ).lines
        ]
        port, console_port, metrics_port = free_port(), free_port(), free_port()
        folder = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="invt-bench-")))
        paths = [line.path for line in lines]
        config = gateway_config(case, paths, port, console_port, metrics_port, folder)
        with gateway(config, port, start_timeout_s=60.0 if case.opcua else 15.0) as process:
            # The Modbus-TCP port listens first; the console, metrics and OPC UA start after
            # it (a loaded machine showed the gap): the case begins once all it uses listen.
            for feature in ("metrics", "console", "opcua"):
                if feature in config:
                    wait_listening(config[feature]["port"], process.process, 60.0)
            clients = None
            if case.opcua:
                clients = stack.enter_context(
                    opcua_clients(config["opcua"]["port"], folder, case.opcua)
                )
            # The clients run in this process: a full collection here held every line's next
            # request back (47 ms at 32 lines), which the case would count against the gateway.
            # On the gateway's own loop (uvloop where installed): 256 clients on asyncio's took
            # a good share of the core the gateway and the drives share with them.
            with collector_paused():
                result = run_on_loop(
                    _measure(
                        case, lines, process, dead, duration_s, warmup_s, console_port, metrics_port
                    ),
                    choose_event_loop(),
                )
            if clients is not None:
                result.opcua = clients.finish()
            return result


async def _measure(
    case: Case,
    lines: list[SimulatorLine],
    process: GatewayProcess,
    dead: list[int],
    duration_s: float,
    warmup_s: float,
    console_port: int = 0,
    metrics_port: int = 0,
) -> CaseResult:
    reads = [await prepare_reads(case, process.port, dead, line) for line in range(case.lines)]
    if case.name.startswith(OPCUA):
        await run_slowly(process.port, [u for line in range(case.lines) for u in case.units(line)])
    measuring, stop = asyncio.Event(), asyncio.Event()
    watching = None
    if case.monitor:
        from gateway.instruments.bench.monitor import watch_traffic  # aiohttp only for this case

        watching = asyncio.create_task(watch_traffic(console_port, stop))
    # A client told its drive is offline asks again after one transaction's time on the wire.
    pause = case.budget.transaction_s
    loads = [
        asyncio.create_task(
            run_clients(process.port, each, frozenset(dead), measuring, stop, pause)
        )
        for each in reads
    ]
    if case.flood:
        flooding = asyncio.create_task(flood(process.port, case.flood, FLOOD_WINDOW, stop))
    # The first scrape before the measured time, by a settling time: the gateway makes its
    # /metrics text on the loop that keeps the lines' gaps (a few ms with 32 lines, in pieces),
    # and that is the bench looking, not the load it measures. The histogram's counts span the
    # settling time too: they give quantiles, not rates.
    settle_s = min(SCRAPE_SETTLE_S, warmup_s / 2)
    await asyncio.sleep(warmup_s - settle_s)
    gaps_before = await excess_gap_buckets(metrics_port)
    await asyncio.sleep(settle_s)
    before = [line.stats() for line in lines]
    cpu_before = process.cpu_s()
    simulators = list({id(line.simulator): line.simulator for line in lines}.values())
    simulators_before = sum(each.cpu_s() for each in simulators)
    waited_before = process.run_queue_s()
    simulators_waited_before = sum(each.run_queue_s() for each in simulators)
    stolen_before = host_steal_s()
    started = time.perf_counter()
    measuring.set()
    await asyncio.sleep(duration_s)
    measuring.clear()
    elapsed = time.perf_counter() - started
    stolen = host_steal_s() - stolen_before
    after = [line.stats() for line in lines]
    cpu = process.cpu_s() - cpu_before
    simulators_cpu = sum(each.cpu_s() for each in simulators) - simulators_before
    waited = process.run_queue_s() - waited_before
    simulators_waited = sum(each.run_queue_s() for each in simulators) - simulators_waited_before
    gaps_after = await excess_gap_buckets(metrics_port)
    stop.set()
    result = LoadResult.merged([await load for load in loads])
    if case.flood:
        await flooding
    if watching is not None:
        await watching  # raises if the monitor never saw the traffic: the case would be void
    per_line = [a["replies"] - b["replies"] for a, b in zip(after, before, strict=True)]
    return CaseResult(
        case=case,
        elapsed_s=elapsed,
        load=result,
        bus_transactions=sum(per_line),
        gap_violations=sum(
            a["gap_violations"] - b["gap_violations"] for a, b in zip(after, before, strict=True)
        ),
        cpu_s=cpu,
        peak_rss_mb=process.peak_rss_mb(),
        rss_mb=process.rss_mb(),
        simulator_cpu_s=simulators_cpu,
        run_queue_s=waited,
        simulator_run_queue_s=simulators_waited,
        host_steal_s=stolen,
        excess_gap=[(le, n - gaps_before.get(le, 0)) for le, n in sorted(gaps_after.items())],
        line_transactions=per_line,
        drive_late=_histogram_change("reply_late_buckets", before, after),
        drive_late_s=sum(
            a["reply_late_s"] - b["reply_late_s"] for a, b in zip(after, before, strict=True)
        ),
        heard_gap=_histogram_change("heard_gap_buckets", before, after),
    )


def _histogram_change(
    key: str, before: list[dict[str, Any]], after: list[dict[str, Any]]
) -> list[tuple[float, int]]:
    """A simulated line's cumulative histogram (`stats[key]`: (`le`, count) pairs) over the
    measured time, every line summed: (upper bound, count) pairs as `quantile` takes them."""
    counts: dict[float, int] = {}
    for stats, sign in [*((each, -1) for each in before), *((each, 1) for each in after)]:
        for le, count in stats.get(key, []):
            bound = float(le)  # "+Inf" too
            counts[bound] = counts.get(bound, 0) + sign * int(count)
    return sorted(counts.items())
