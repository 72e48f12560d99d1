"""`stress --soak HOURS`: hours of a plant's traffic, compressed, against one gateway process,
with its memory, open files and CPU per transaction sampled all along.

The traffic, all the time: Modbus-TCP clients writing and reading back parameters they own
(`CheckedLoad`, every value checked), an HMI connecting for each read (`BriefScada`), an MQTT
dashboard sending set-points, parameter reads, fault-history requests and polls now
(`MqttCommands`), a console viewer going round its pages, events, CSV exports and history
charts and logging in and out (`ConsoleViewer`), Prometheus scraping `/metrics` and `/health`
(`Scraper`), the poller and the history store at a step of a second (60 times a plant's
minute).

The faults, every round of `ROUND_S` (a shorter run does one round in its time, each fault's
length scaled by as much):

    10 %   drive 2 trips, and is reset over MQTT (fault_reset) a few seconds later
    30 %   drive 3 stalls (answers nothing, then all it took at once)
    50 %   the broker is killed, and started again 20 s later
    65 %   drive 4 trips, and is reset
    80 %   the store's disk is full for a minute (a tmpfs of its own, filled; needs root to
           mount, as the tests' `small_disk`: without it, this fault is left out and said so)

The verdict (`gateway.instruments.stress.soak_report`): no wrong value, no error a fault
doesn't explain (only the broker's outage excuses MQTT's, only a stalled drive Modbus-TCP's),
and resident memory growing at most `MAX_GROWTH_MB_PER_HOUR` after the warm-up, judged on a
run whose measured part lasts `MIN_JUDGED_S` at least.
"""

from __future__ import annotations

import asyncio
import os
import tempfile
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

from gateway.instruments.bench.processes import (
    SimulatorProcess,
    cpu_s,
    free_port,
    stop_process,
    wait_listening,
)
from gateway.instruments.stress.checked_load import CheckedLoad, LoadStats
from gateway.instruments.stress.memory_growth import Growth, growth_between
from gateway.instruments.stress.processes import (
    Broker,
    Gateway,
    launch_simulator,
    mosquitto_path,
    simulator_started,
)
from gateway.instruments.stress.soak_clients import (
    BriefScada,
    CallStats,
    ConsoleViewer,
    MqttCommands,
    Outages,
    Scraper,
)
from gateway.instruments.stress.soak_faults import ROUND_S, Faults, SimulatorControl, store_disk
from gateway.memory_trace import ENVIRONMENT, SIGNAL, SUFFIX
from gateway.passwords import hash_password, hash_token

WARM_UP_S: Final = 1200.0
"""The console's live charts full (15 minutes of a point a second per drive), caches filled,
the store's pages in use, the allocator settled."""
SAMPLE_S: Final = 60.0
RSS_EVERY_S: Final = 1.0
MIN_JUDGED_S: Final = 1200.0
"""A growth rate from less than this after the warm-up is the allocator's noise."""
STORE_MB: Final = 2.0
DRIVES: Final = 4
CLIENTS: Final = 4
"""Modbus-TCP clients: one per drive, each writing its block and reading it back."""
MQTT_PAUSE_S: Final = 0.2
CONSOLE_PAUSE_S: Final = 0.2
SCRAPE_PAUSE_S: Final = 1.0
BRIEF_PAUSE_S: Final = 0.2
VIEWER: Final = ("victor", "viewer-soak-secret-1", "viewer-soak-token-0123456789abcdef")
SNAPSHOT_WAIT_S: Final = 60.0


@dataclass(frozen=True, slots=True)
class SoakSettings:
    hours: float
    seed: int = 1
    snapshots: Path | None = None
    """A folder for the gateway's tracemalloc snapshots (`gateway.memory_trace`), or None."""

    @property
    def duration_s(self) -> float:
        return self.hours * 3600.0

    @property
    def round_s(self) -> float:
        return min(ROUND_S, self.duration_s)

    @property
    def warm_up_s(self) -> float:
        return min(WARM_UP_S, self.duration_s / 4)

    @property
    def sample_s(self) -> float:
        return min(SAMPLE_S, max(1.0, self.duration_s / 12))


@dataclass(frozen=True, slots=True)
class Sample:
    at_s: float
    """Seconds since the traffic started."""
    rss_mb: float
    """The lowest resident memory seen in the interval the sample ends (read every second)."""
    open_files: int
    cpu_s: float
    """The gateway's CPU time since it started."""
    transactions: int
    """Frames the simulated drives were sent since the start (bus transactions, retries too)."""


@dataclass
class SoakResult:
    settings: SoakSettings
    elapsed_s: float = 0.0
    samples: list[Sample] = field(default_factory=list)
    load: LoadStats = field(default_factory=LoadStats)
    mqtt: CallStats = field(default_factory=CallStats)
    console: CallStats = field(default_factory=CallStats)
    scrapes: CallStats = field(default_factory=CallStats)
    brief: CallStats = field(default_factory=CallStats)
    """Reads on a connection of their own each."""
    faults: Counter[str] = field(default_factory=Counter)
    """Faults carried out, by kind."""
    left_out: dict[str, str] = field(default_factory=dict)
    """Faults not run, and why."""
    gateway_exit: int | None = None
    """The gateway's exit code if it ended before the run did."""
    growth: list[Growth] = field(default_factory=list)
    """The lines whose allocations grew most after the warm-up (with `snapshots`)."""
    gateway_log: str = ""


async def run_soak(
    settings: SoakSettings, progress: Callable[[str], None] = lambda _: None
) -> SoakResult:
    result = SoakResult(settings)
    executable = mosquitto_path()
    if executable is None:
        raise RuntimeError("the soak needs mosquitto (Debian's package) for its MQTT traffic")
    with tempfile.TemporaryDirectory(prefix="invt-soak-") as folder:
        directory = Path(folder)
        link = directory / "ttyRS485"
        broker = Broker(executable, directory)
        arguments = ["--link", str(link), "--baud", "115200", "--parity", "N"]
        launched = launch_simulator([*arguments, *_addresses()])
        gateway: Gateway | None = None
        with store_disk(directory / "store", result.left_out) as store:
            try:
                simulator = await asyncio.to_thread(simulator_started, launched)
                broker.start()
                await asyncio.to_thread(broker.wait_listening)
                config = _gateway_config(link, store, broker)
                gateway = Gateway(config, directory, _tracing(settings))
                gateway.start()
                await asyncio.to_thread(gateway.wait_listening)
                # The console and /metrics start after Modbus-TCP: the traffic waits for them.
                assert gateway.process is not None
                for section in (config["console"], config["metrics"]):
                    await asyncio.to_thread(wait_listening, section["port"], gateway.process)
                await _run(settings, config, simulator, gateway, broker, store, result, progress)
            finally:
                if gateway is not None:
                    result.gateway_log = gateway.log_tail()
                    await asyncio.to_thread(gateway.stop)
                await asyncio.to_thread(broker.stop)
                await asyncio.to_thread(stop_process, launched)
    return result


async def _run(
    settings: SoakSettings,
    config: dict[str, Any],
    simulator: SimulatorProcess,
    gateway: Gateway,
    broker: Broker,
    store: Path | None,
    result: SoakResult,
    progress: Callable[[str], None],
) -> None:
    outages = Outages()
    drives = [drive["name"] for drive in config["drives"]]
    base_topic = config["mqtt"]["base_topic"]
    load = CheckedLoad(gateway.port, _unit_ids(), CLIENTS, settings.seed)
    mqtt = MqttCommands(broker.host, broker.port, base_topic, drives, outages)
    console = ConsoleViewer(_url(config["console"]), VIEWER[2], VIEWER[0], VIEWER[1], drives)
    scraper = Scraper(_url(config["metrics"]))
    brief = BriefScada(gateway.port, 1)
    stop = asyncio.Event()
    started = time.monotonic()
    line = SimulatorControl(simulator)
    faults = Faults(settings.round_s, line, broker, load, mqtt, outages, store, result.faults)
    async with asyncio.TaskGroup() as tasks:
        users = [
            tasks.create_task(load.run(stop), name="soak:modbus"),
            tasks.create_task(mqtt.run(stop, MQTT_PAUSE_S), name="soak:mqtt"),
            tasks.create_task(console.run(stop, CONSOLE_PAUSE_S), name="soak:console"),
            tasks.create_task(scraper.run(stop, SCRAPE_PAUSE_S), name="soak:scrape"),
            tasks.create_task(brief.run(stop, BRIEF_PAUSE_S), name="soak:brief-scada"),
        ]
        sampling = tasks.create_task(
            _sample(settings, gateway, line, started, result, progress), name="soak:sample"
        )
        try:
            await faults.rounds(started, started + settings.duration_s)
            await _sleep_until(started + settings.duration_s)
        finally:
            stop.set()
        await sampling
        await asyncio.gather(*users)
    result.elapsed_s = time.monotonic() - started
    result.load = load.stats
    result.mqtt = mqtt.stats
    result.console = console.stats
    result.scrapes = scraper.stats
    result.brief = brief.stats
    if gateway.process is not None:
        result.gateway_exit = gateway.process.poll()


async def _sample(
    settings: SoakSettings,
    gateway: Gateway,
    line: SimulatorControl,
    started: float,
    result: SoakResult,
    progress: Callable[[str], None],
) -> None:
    """A sample every `sample_s` to the end; tracemalloc snapshots after the warm-up and at
    the end, compared."""
    assert gateway.process is not None
    pid = gateway.process.pid
    first_frames = await line.frames()
    first_snapshot: Path | None = None
    end = started + settings.duration_s
    moment = started
    while moment < end:
        moment = min(moment + settings.sample_s, end)
        try:
            # The lowest RSS of the interval: what the gateway comes back to between
            # transient allocations (a chart, a CSV file, a batch the disk took late), so that
            # a sample caught in one doesn't pass for growth.
            low_mb = await _lowest_rss(gateway, moment)
            frames = await line.frames() - first_frames
            sample = _measure(pid, time.monotonic() - started, frames, low_mb)
        except OSError:  # the gateway is gone: the verdict says so (`gateway_exit`)
            return
        result.samples.append(sample)
        progress(
            f"{sample.at_s / 60:.1f} min: RSS {sample.rss_mb:.1f} MB, "
            f"{sample.open_files} open files, {sample.transactions} transactions"
        )
        snapshots = settings.snapshots
        warm = sample.at_s >= settings.warm_up_s
        if snapshots is not None and warm and (first_snapshot is None or moment >= end):
            taken = await _snapshot(pid, snapshots)
            if first_snapshot is None:
                first_snapshot = taken
            elif taken is not None:
                result.growth = await asyncio.to_thread(growth_between, first_snapshot, taken)


async def _lowest_rss(gateway: Gateway, until: float) -> float:
    lowest = gateway.memory_mb()[0]
    while time.monotonic() < until:
        await asyncio.sleep(min(RSS_EVERY_S, max(0.0, until - time.monotonic())))
        lowest = min(lowest, gateway.memory_mb()[0])
    return lowest


def _measure(pid: int, at_s: float, transactions: int, rss_mb: float) -> Sample:
    open_files = len(os.listdir(f"/proc/{pid}/fd"))
    return Sample(at_s, rss_mb, open_files, cpu_s(pid), transactions)


async def _snapshot(pid: int, folder: Path) -> Path | None:
    """Ask the gateway for a tracemalloc snapshot (SIGUSR2) and wait until it is written."""
    before = _snapshots(folder, pid)
    os.kill(pid, SIGNAL)
    deadline = time.monotonic() + SNAPSHOT_WAIT_S
    while time.monotonic() < deadline:
        new = sorted(_snapshots(folder, pid) - before)
        if new:
            return new[-1]
        await asyncio.sleep(0.2)
    return None


def _snapshots(folder: Path, pid: int) -> set[Path]:
    return set(folder.glob(f"snapshot-{pid}-*{SUFFIX}"))


def _tracing(settings: SoakSettings) -> dict[str, str]:
    if settings.snapshots is None:
        return {}
    return {ENVIRONMENT: str(settings.snapshots.resolve())}


async def _sleep_until(moment: float) -> None:
    await asyncio.sleep(max(0.0, moment - time.monotonic()))


def _unit_ids() -> list[int]:
    return list(range(1, DRIVES + 1))


def _addresses() -> list[str]:
    return [word for unit_id in _unit_ids() for word in ("--address", str(unit_id))]


def _url(section: dict[str, Any]) -> str:
    return f"http://{section['host']}:{section['port']}"


def _gateway_config(link: Path, store: Path | None, broker: Broker) -> dict[str, Any]:
    name, password, token = VIEWER
    folder = store if store is not None else link.parent / "store"
    return {
        "gateway_id": "soak",
        "modbus_tcp": {"host": "127.0.0.1", "port": free_port(), "max_connections": 64},
        "buses": [
            {
                "name": "line1",
                "port": str(link),
                "baudrate": 115200,
                "parity": "N",  # a Linux pty refuses re-configuration once a parity is set
                "timeout_ms": 50,
                "drain_ms": 150,
                "retries": 2,
                "char_timeout_ms": 10,
            }
        ],
        "drives": [
            {"name": f"drive{unit_id}", "bus": "line1", "address": unit_id, "model": "gd350"}
            for unit_id in _unit_ids()
        ],
        "logging": {"level": "warning"},
        # A history point a second: the store's writes and charts of an hour in a minute. Its
        # bound is reached about when the warm-up ends (some 5 MB an hour of history), so that
        # after it the store's oldest history goes as the new comes, as on a plant's box after
        # its first week: a store still filling makes every chart's work (and its memory) grow.
        "storage": {
            "path": str(folder / "events.db"),
            "history_step_s": 1,
            "max_mb": STORE_MB,
        },
        "mqtt": {
            "host": broker.host,
            "port": broker.port,
            "base_topic": f"invt-soak-{os.getpid()}",
            "homeassistant_discovery": False,
            "reconnect_max_s": 1.0,
            "publish_interval_s": 5,
        },
        "console": {
            "enabled": True,
            "host": "127.0.0.1",
            "port": free_port(),
            "users": [
                {
                    "name": name,
                    "password_hash": hash_password(password),
                    "role": "viewer",
                    "token_hash": hash_token(token),
                }
            ],
        },
        "metrics": {"enabled": True, "host": "127.0.0.1", "port": free_port()},
    }
