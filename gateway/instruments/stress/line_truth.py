"""`invt-gateway stress --line-truth`: many drives, late ones, and devices that know only reads
and writes, on one line, with every value checked.

Four drives on one simulated line at the bus's defaults (300 ms timeout, 2 retries): a share of
each drive's replies comes late by a random 0-1000 ms (a drive writing its EEPROM), a share of
its requests is dropped (noise at its end), and every few seconds one of them stalls for 0.4-3 s
and then answers what it took meanwhile, in order. Drives 3 and 4 frame only 03H, 04H, 06H and
10H: they stay silent to the diagnostic echo (08H), as libmodbus devices do. Modbus-TCP clients
write and read back parameter blocks whose true values they know (`CheckedLoad`).

The verdict: no wrong value at all, and every drive answering right within 1 s of each stall's
end (its first answer after a stall is the late reply to what it took meanwhile).
"""

from __future__ import annotations

import asyncio
import random
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from gateway.instruments.bench.processes import free_port, stop_process
from gateway.instruments.stress.checked_load import CheckedLoad, LoadStats
from gateway.instruments.stress.processes import Gateway, launch_simulator, simulator_started

DRIVES = (1, 2, 3, 4)
WITHOUT_08H = (3, 4)
ONLY_READS_AND_WRITES = "03,04,06,10"
LATE_SHARE = 0.002
"""Of each drive's replies, this share comes late by a random 0-1000 ms: each such reply holds
the line for a timeout, its retries and a marker (up to a second), so a larger share leaves the
line to the late drives and the run checks few reads."""
LATE_MS = "0-1000"
DROP_RATE = 0.001
STALL_EVERY_S = (10.0, 20.0)
FIRST_STALL_S = (2.0, 5.0)
STALL_S = (0.4, 3.0)
BACK_WITHIN_S = 1.0
CLIENTS = 12


@dataclass(frozen=True, slots=True)
class Stall:
    unit_id: int
    seconds: float
    ended_at: float
    back_after_s: float | None = None
    """From the stall's end to the drive's first right answer; None: not within 30 s."""


@dataclass
class LineTruthResult:
    duration_s: float
    seed: int
    elapsed_s: float = 0.0
    load: LoadStats = field(default_factory=LoadStats)
    stalls: list[Stall] = field(default_factory=list)
    simulator: dict[str, Any] = field(default_factory=dict)
    gateway_log: str = ""

    @property
    def slowest_back_s(self) -> float | None:
        times = [s.back_after_s for s in self.stalls]
        return None if any(t is None for t in times) else max((t or 0.0 for t in times), default=0)

    def problems(self) -> list[str]:
        found = []
        if self.load.wrong:
            found.append(f"{self.load.wrong} wrong values: {self.load.wrong_examples[:3]}")
        for stall in self.stalls:
            if stall.back_after_s is None or stall.back_after_s > BACK_WITHIN_S:
                back = "never" if stall.back_after_s is None else f"{stall.back_after_s:.2f} s"
                found.append(
                    f"drive {stall.unit_id} back {back} after a {stall.seconds:.1f} s stall"
                )
        if not self.load.checked_reads:
            found.append("no read was answered")
        return found


async def run_line_truth(
    duration_s: float, seed: int, progress: Callable[[str], None] = lambda _: None
) -> LineTruthResult:
    result = LineTruthResult(duration_s, seed)
    with tempfile.TemporaryDirectory(prefix="invt-line-truth-") as folder:
        directory = Path(folder)
        link = directory / "ttyRS485"
        # Drives answering 2 ms after a request (P14.03 can be 0-200 ms): the run's anomalies,
        # not the drives' own delay, should be what holds the line.
        arguments = ["--link", str(link), "--baud", "115200", "--parity", "N"]
        arguments += ["--response-delay-ms", "2"]
        for unit_id in DRIVES:
            arguments += ["--address", str(unit_id)]
        launched = launch_simulator(arguments)
        gateway: Gateway | None = None
        try:
            simulator = await asyncio.to_thread(simulator_started, launched)
            for unit_id in DRIVES:
                for command in (
                    f"slow {unit_id} {LATE_MS} {LATE_SHARE}",
                    f"drop {unit_id} {DROP_RATE}",
                    *(
                        [f"knows {unit_id} {ONLY_READS_AND_WRITES}"]
                        if unit_id in WITHOUT_08H
                        else []
                    ),
                ):
                    answer = await asyncio.to_thread(simulator.command, command)
                    if not answer.startswith("ok"):
                        raise RuntimeError(f"the simulator refused {command!r}: {answer}")
            gateway = Gateway(_gateway_config(link), directory)
            gateway.start()
            await asyncio.to_thread(gateway.wait_listening)
            progress(f"{duration_s:g} s: late replies, drops, stalls; drives 3 and 4 without 08H")
            load = CheckedLoad(gateway.port, list(DRIVES), CLIENTS, seed)
            stop = asyncio.Event()
            started = time.monotonic()
            async with asyncio.TaskGroup() as tasks:
                load_task = tasks.create_task(load.run(stop), name="line-truth:load")
                try:
                    await _stall_now_and_then(
                        simulator.command, load, started + duration_s, seed, result, progress
                    )
                finally:
                    stop.set()
                await load_task
            result.elapsed_s = time.monotonic() - started
            result.load = load.stats
            result.simulator = await asyncio.to_thread(simulator.stats)
        finally:
            if gateway is not None:
                result.gateway_log = gateway.log_tail()
                await asyncio.to_thread(gateway.stop)
            await asyncio.to_thread(stop_process, launched)
    return result


async def _stall_now_and_then(
    command: Callable[[str], str],
    load: CheckedLoad,
    until: float,
    seed: int,
    result: LineTruthResult,
    progress: Callable[[str], None],
) -> None:
    rng = random.Random(seed)
    pause = rng.uniform(*FIRST_STALL_S)
    while time.monotonic() + pause < until - STALL_S[1] - BACK_WITHIN_S:
        await asyncio.sleep(pause)
        pause = rng.uniform(*STALL_EVERY_S)
        unit_id, seconds = rng.choice(DRIVES), rng.uniform(*STALL_S)
        await asyncio.to_thread(command, f"stall {unit_id} {seconds:.3f}")
        await asyncio.sleep(seconds)
        ended_at = time.monotonic()
        back = await _first_right_answer(load, unit_id, ended_at)
        result.stalls.append(Stall(unit_id, seconds, ended_at, back))
        progress(
            f"drive {unit_id}: stalled {seconds:.1f} s, "
            + ("NOT back" if back is None else f"back {back:.2f} s after")
            + f"; {load.stats.checked_reads} reads checked, {load.stats.wrong} wrong"
        )
    await asyncio.sleep(max(0.0, until - time.monotonic()))


async def _first_right_answer(load: CheckedLoad, unit_id: int, moment: float) -> float | None:
    deadline = moment + 30.0
    while time.monotonic() < deadline:
        last = load.stats.last_ok_by_unit.get(unit_id, 0.0)
        if last > moment:
            return last - moment
        await asyncio.sleep(0.005)
    return None


def _gateway_config(link: Path) -> dict[str, Any]:
    return {
        "gateway_id": "line-truth",
        "modbus_tcp": {"host": "127.0.0.1", "port": free_port(), "max_connections": 64},
        "buses": [
            # The defaults a user starts with: 300 ms, 2 retries. Parity N: a pty refuses
            # re-configuration once a parity is set.
            {"name": "line1", "port": str(link), "baudrate": 115200, "parity": "N"}
        ],
        "drives": [
            {"name": f"drive{unit_id}", "bus": "line1", "address": unit_id, "model": "gd350"}
            for unit_id in DRIVES
        ],
        "logging": {"level": "warning"},
        # Its own store in the run's folder: two runs at once never share one (a store has
        # one owner), and nothing is left in /var/lib.
        "storage": {"path": str(link.parent / "events.db")},
    }


def line_truth_table(result: LineTruthResult) -> str:
    load = result.load
    backs = [s.back_after_s for s in result.stalls if s.back_after_s is not None]
    rows = [
        ("duration", f"{result.elapsed_s:.0f} s (seed {result.seed})"),
        ("reads checked", f"{load.checked_reads}"),
        ("right answers (reads and writes)", f"{load.answered}"),
        ("wrong values", f"{load.wrong}"),
        ("errors (0BH and the like)", f"{sum(load.errors.values())}"),
        ("stalls", f"{len(result.stalls)} (0.4-3 s)"),
        ("back after a stall, slowest", f"{max(backs):.2f} s" if backs else "-"),
        ("back after a stall, median", f"{sorted(backs)[len(backs) // 2]:.2f} s" if backs else "-"),
        ("requests on the line", f"{result.simulator.get('requests', 0)}"),
        ("requests left silent (no 08H, drops)", f"{result.simulator.get('ignored', 0)}"),
    ]
    width = max(len(name) for name, _ in rows)
    lines = [f"{name:<{width}}  {value}" for name, value in rows]
    problems = result.problems()
    lines.append("verdict: " + ("PASS" if not problems else "FAIL: " + "; ".join(problems)))
    return "\n".join(lines)
