"""The stress run: checked Modbus-TCP load through a faulty line for the whole duration, and one
hard fault after another, each timed until the clients (or the broker) see the gateway back.

    0 %     simulator (line faults on), broker, gateway; the clients start, and a hostile
            one sending random and malformed MBAP frames
    15 %    the gateway is killed (SIGKILL) and started again      → first right answer
            memory measured once it serves again
    45 %    the serial port is unplugged, then plugged back in     → first right answer
    70 %    the broker is killed, then started again               → the gateway online on it
    100 %   memory measured again; counters collected

Errors during an outage of the gateway or of its serial port are expected and counted apart; a
broker outage must cost Modbus-TCP nothing, so its errors count as steady ones.
"""

from __future__ import annotations

import asyncio
import logging
import os
import tempfile
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from gateway.instruments.bench.processes import SimulatorProcess, free_port, stop_process
from gateway.instruments.stress.checked_load import STEADY, CheckedLoad, LoadStats
from gateway.instruments.stress.hostile import HostileClient, HostileStats
from gateway.instruments.stress.processes import (
    Broker,
    Gateway,
    launch_simulator,
    mosquitto_path,
    simulator_started,
)

if TYPE_CHECKING:
    from gateway.instruments.stress.broker_watch import OnlineWatch

log = logging.getLogger(__name__)

TIMEOUT_MS = 50
DRAIN_MS = 150
LATE_REPLY_MS = 100
"""After the response timeout, inside the drain: the gateway hears a late reply out and drops it."""
DEFAULT_WINDOW_MS = 300 + 50
"""A bus's default response timeout and drain, which a slow drive's run keeps."""
RECOVERY_LIMIT_S = 30.0
SETTLE_S = 0.5
"""After a recovery, answers to requests sent during the outage may still come back as errors."""
EVENT_AT = {"gateway SIGKILL": 0.15, "serial port": 0.45, "MQTT broker": 0.70}


@dataclass(frozen=True, slots=True)
class StressSettings:
    duration_s: float = 60.0
    fault_rate: float = 0.05
    clients: int = 8
    drives: int = 4
    baudrate: int = 115200
    seed: int = 1
    outage_s: float = 1.0
    """How long the serial port and the broker stay away."""
    late_ms: tuple[float, float] = (LATE_REPLY_MS, LATE_REPLY_MS)
    """How late a 'late' reply comes: drawn from this range (ms)."""
    slow_drive_ms: tuple[float, float] | None = None
    """Drive 1 answers every request this much late, drawn from the range for each reply."""

    @property
    def late_beyond_drain(self) -> bool:
        """Can a reply outlast the response timeout and the drain? Then it fails its request
        (and the drive's next ones while it is behind) by design: errors are expected, and
        only wrong values are judged."""
        window = TIMEOUT_MS + DRAIN_MS
        slow = self.slow_drive_ms is not None and self.slow_drive_ms[1] > DEFAULT_WINDOW_MS
        return slow or (self.fault_rate > 0 and self.late_ms[1] > window)


@dataclass(frozen=True, slots=True)
class Recovery:
    what: str
    measured_from: str
    seconds: float | None
    """None: not back within RECOVERY_LIMIT_S."""


@dataclass
class StressResult:
    settings: StressSettings
    elapsed_s: float = 0.0
    frames: int = 0
    faults_injected: int = 0
    faults_by_kind: dict[str, int] = field(default_factory=dict)
    load: LoadStats = field(default_factory=LoadStats)
    hostile: HostileStats = field(default_factory=HostileStats)
    recoveries: list[Recovery] = field(default_factory=list)
    memory_start_mb: float = 0.0
    memory_end_mb: float = 0.0
    memory_peak_mb: float = 0.0
    broker: bool = False
    gateway_log: str = ""

    @property
    def steady_requests(self) -> int:
        return self.load.requests[STEADY]

    @property
    def steady_errors(self) -> int:
        return self.load.errors[STEADY]

    @property
    def error_rate(self) -> float:
        return self.steady_errors / self.steady_requests if self.steady_requests else 0.0


async def run_stress(
    settings: StressSettings, progress: Callable[[str], None] = lambda _: None
) -> StressResult:
    result = StressResult(settings)
    with tempfile.TemporaryDirectory(prefix="invt-stress-") as folder:
        directory = Path(folder)
        link = directory / "ttyRS485"
        executable = mosquitto_path()
        broker = Broker(executable, directory) if executable else None
        gateway: Gateway | None = None
        # Each process is started here, on the loop's thread (`die_with_parent`), and held at
        # once: the `finally` stops it even when the run ends before it is ready.
        launched = launch_simulator(_simulator_arguments(settings, link))
        try:
            simulator = await asyncio.to_thread(simulator_started, launched)
            if broker is not None:
                broker.start()
                await asyncio.to_thread(broker.wait_listening)
                result.broker = True
            gateway = Gateway(_gateway_config(settings, link, broker), directory)
            gateway.start()
            await asyncio.to_thread(gateway.wait_listening)
            progress(f"{settings.duration_s:g} s, {settings.fault_rate:.1%} of replies spoilt")
            await _run(settings, simulator, gateway, broker, result, progress)
        finally:
            if gateway is not None:
                result.gateway_log = gateway.log_tail()
                await asyncio.to_thread(gateway.stop)
            if broker is not None:
                await asyncio.to_thread(broker.stop)
            await asyncio.to_thread(stop_process, launched)
    return result


async def _run(
    settings: StressSettings,
    simulator: SimulatorProcess,
    gateway: Gateway,
    broker: Broker | None,
    result: StressResult,
    progress: Callable[[str], None],
) -> None:
    load = CheckedLoad(gateway.port, _unit_ids(settings), settings.clients, settings.seed)
    hostile = HostileClient(gateway.port, settings.seed)
    stop = asyncio.Event()
    started = time.monotonic()
    watch: OnlineWatch | None = None
    watch_task: asyncio.Task[None] | None = None
    async with asyncio.TaskGroup() as tasks:
        load_task = tasks.create_task(load.run(stop), name="stress:load")
        tasks.create_task(hostile.run(stop), name="stress:hostile")
        if broker is not None:
            from gateway.instruments.stress.broker_watch import (
                OnlineWatch,  # aiomqtt only with a broker
            )

            watch = OnlineWatch(broker.host, broker.port, _base_topic())
            watch_task = tasks.create_task(watch.run(), name="stress:watch")
        try:
            events: list[tuple[str, Callable[[], Awaitable[Recovery]]]] = [
                ("gateway SIGKILL", lambda: _kill_gateway(gateway, load, hostile)),
                ("serial port", lambda: _unplug(simulator, load, settings.outage_s)),
            ]
            if broker is not None and watch is not None:
                events.append(
                    ("MQTT broker", lambda: _restart_broker(broker, watch, settings.outage_s))
                )
            for what, event in events:
                await _sleep_until(started + EVENT_AT[what] * settings.duration_s)
                recovery = await event()
                result.recoveries.append(recovery)
                progress(_describe(recovery))
                if what == "gateway SIGKILL":
                    await asyncio.sleep(1.0)  # serving again: imports done, buffers warm
                    result.memory_start_mb, _ = gateway.memory_mb()
            await _sleep_until(started + settings.duration_s)
            result.memory_end_mb, result.memory_peak_mb = gateway.memory_mb()
        finally:
            stop.set()
            if watch_task is not None:
                watch_task.cancel()
        await load_task
    result.elapsed_s = time.monotonic() - started
    result.load = load.stats
    result.hostile = hostile.stats
    stats = await asyncio.to_thread(simulator.stats)
    result.frames = int(stats["requests"])
    result.faults_injected = int(stats["faults_injected"])
    result.faults_by_kind = dict(sorted(stats["faults_by_kind"].items()))


async def _kill_gateway(gateway: Gateway, load: CheckedLoad, hostile: HostileClient) -> Recovery:
    load.phase = "gateway SIGKILL"
    # Its connections open now, or opened until the old process is gone, are closed by the kill,
    # not by the gateway.
    hostile.kills += 1
    killed_at = time.monotonic()
    await asyncio.to_thread(gateway.kill)
    hostile.kills += 1
    gateway.start()
    seconds = await first_answer_after(load, killed_at, new_connection=True)
    return Recovery("gateway SIGKILL", "killed", seconds)


async def _unplug(simulator: SimulatorProcess, load: CheckedLoad, outage_s: float) -> Recovery:
    load.phase = "serial port"
    await asyncio.to_thread(simulator.command, "unplug")
    await asyncio.sleep(outage_s)
    await asyncio.to_thread(simulator.command, "replug")
    replugged_at = time.monotonic()
    seconds = await first_answer_after(load, replugged_at)
    return Recovery("serial port", "plugged back in", seconds)


async def _restart_broker(broker: Broker, watch: OnlineWatch, outage_s: float) -> Recovery:
    await asyncio.to_thread(broker.kill)
    await asyncio.sleep(outage_s)
    broker.start()
    await asyncio.to_thread(broker.wait_listening)
    started_at = time.monotonic()
    deadline = started_at + RECOVERY_LIMIT_S
    while time.monotonic() < deadline:
        online = watch.first_online_after(started_at)
        if online is not None:
            return Recovery("MQTT broker", "restarted", online - started_at)
        await asyncio.sleep(0.01)
    return Recovery("MQTT broker", "restarted", None)


async def first_answer_after(
    load: CheckedLoad, moment: float, new_connection: bool = False
) -> float | None:
    """Seconds from `moment` to the first right answer after it (on a connection opened after
    it, if `new_connection`); then back to steady."""
    deadline = moment + RECOVERY_LIMIT_S
    stats = load.stats
    try:
        while time.monotonic() < deadline:
            fresh = not new_connection or stats.last_ok_connected_at > moment
            if stats.last_ok_at > moment and fresh:
                return stats.last_ok_at - moment
            await asyncio.sleep(0.005)
        return None
    finally:
        await asyncio.sleep(SETTLE_S)
        load.phase = STEADY


async def _sleep_until(moment: float) -> None:
    await asyncio.sleep(max(0.0, moment - time.monotonic()))


def _describe(recovery: Recovery) -> str:
    if recovery.seconds is None:
        return f"{recovery.what}: NOT back within {RECOVERY_LIMIT_S:.0f} s"
    return f"{recovery.what}: back {recovery.seconds:.2f} s after it was {recovery.measured_from}"


def _unit_ids(settings: StressSettings) -> list[int]:
    return list(range(1, settings.drives + 1))


def _base_topic() -> str:
    return f"invt-stress-{os.getpid()}"


def _simulator_arguments(settings: StressSettings, link: Path) -> list[str]:
    arguments = ["--link", str(link), "--baud", str(settings.baudrate), "--parity", "N"]
    for unit_id in _unit_ids(settings):
        arguments += ["--address", str(unit_id)]
    if settings.slow_drive_ms is not None:
        low, high = settings.slow_drive_ms
        arguments += ["--slow", f"1={low:g}-{high:g}"]
    if settings.fault_rate > 0:
        arguments += ["--line-faults", str(settings.fault_rate)]
        arguments += ["--line-fault-seed", str(settings.seed)]
        low, high = settings.late_ms
        arguments += ["--late-reply-ms", f"{low:g}-{high:g}"]
    return arguments


def _gateway_config(settings: StressSettings, link: Path, broker: Broker | None) -> dict[str, Any]:
    config: dict[str, Any] = {
        "gateway_id": "stress",
        "modbus_tcp": {"host": "127.0.0.1", "port": free_port(), "max_connections": 64},
        "buses": [
            {
                "name": "line1",
                "port": str(link),
                "baudrate": settings.baudrate,
                # Parity N: a Linux pty refuses re-configuration once a parity is set.
                "parity": "N",
                # A slow drive meets the defaults a user starts with (300 ms, drain 50 ms).
                **(
                    {"timeout_ms": TIMEOUT_MS, "drain_ms": DRAIN_MS}
                    if settings.slow_drive_ms is None
                    else {}
                ),
                "retries": 2,
                "char_timeout_ms": 10,
            }
        ],
        "drives": [
            {"name": f"drive{unit_id}", "bus": "line1", "address": unit_id, "model": "gd350"}
            for unit_id in _unit_ids(settings)
        ],
        "logging": {"level": "warning"},
        # Its own store in the run's folder: two runs at once never share one (a store has
        # one owner), and nothing is left in /var/lib.
        "storage": {"path": str(link.parent / "events.db")},
    }
    if broker is not None:
        config["mqtt"] = {
            "host": broker.host,
            "port": broker.port,
            "base_topic": _base_topic(),
            "homeassistant_discovery": False,
            "reconnect_max_s": 1.0,
            "publish_interval_s": 5,
        }
    return config
