"""`stress --history`: months of history kept, and a dashboard's worth of charts over all of it
asked at once, while SCADA reads: does the gateway keep its memory and its Modbus-TCP pace?

    1  the store is filled with `days` of history of each drive at a point a minute (the
       store's own writer, `EventDatabase.append`, as the service would have written it)
    2  the gateway starts on it; Modbus-TCP clients read for `phase_s` (unloaded: the
       latency's p99, the resident memory at rest)
    3  the same clients read on while `queries` console clients each ask for the whole window
       of a drive's every value, again and again, for `phase_s`: RSS sampled all along,
       the p99 again

It passes when the loaded RSS peak stays within `MAX_RSS_GROWTH_MB` of the idle one, the
loaded p99 within `MAX_P99_GROWTH` of the unloaded one, every history answer was 200 or a
503 with Retry-After (the console's bound), at least one of each client was answered, and
no Modbus-TCP read failed.
"""

from __future__ import annotations

import asyncio
import random
import secrets
import struct
import tempfile
import time
from collections import Counter
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Final

import aiohttp

from gateway.instruments.bench.processes import free_port, stop_process, wait_listening
from gateway.instruments.stress.processes import Gateway, launch_simulator, simulator_started
from gateway.passwords import hash_password, hash_token
from gateway.store.database import Batch, EventDatabase
from gateway.store.records import HistoryPoint

DRIVES: Final = ("pump1", "pump2")
STEP_S: Final = 60.0
BAUDRATE: Final = 115200
FILL_BATCH: Final = 20_000
READ_REGISTER: Final = 0x000A  # P00.10..P00.11: parameters nobody writes here
READ_COUNT: Final = 2
REPLY_TIMEOUT_S: Final = 5.0
ANSWER_TIMEOUT_S: Final = 120.0
SAMPLE_S: Final = 0.1
MAX_RSS_GROWTH_MB: Final = 50.0
MAX_P99_GROWTH: Final = 0.20
TOKEN: Final = "history-load-token-0123456789abcdef"
POINTS: Final = 800
"""What the console's history page asks for (`history.js`): a chart's width."""


@dataclass(frozen=True, slots=True)
class HistoryLoadSettings:
    days: float = 90.0
    queries: int = 10
    phase_s: float = 30.0
    readers: int = 2


@dataclass
class Phase:
    reads: int = 0
    errors: int = 0
    latencies_s: list[float] = field(default_factory=list)
    rss_mb: list[float] = field(default_factory=list)

    @property
    def p99_ms(self) -> float:
        return percentile(self.latencies_s, 0.99) * 1000

    @property
    def rss_peak_mb(self) -> float:
        return max(self.rss_mb, default=0.0)


@dataclass
class HistoryLoadResult:
    settings: HistoryLoadSettings
    rows: int = 0
    store_mb: float = 0.0
    fill_s: float = 0.0
    unloaded: Phase = field(default_factory=Phase)
    loaded: Phase = field(default_factory=Phase)
    answers: Counter[int] = field(default_factory=Counter)
    """History answers by HTTP status."""
    answer_s: list[float] = field(default_factory=list)
    failures: list[str] = field(default_factory=list)
    gateway_log: str = ""


async def run_history_load(settings: HistoryLoadSettings) -> HistoryLoadResult:
    result = HistoryLoadResult(settings)
    with tempfile.TemporaryDirectory(prefix="invt-history-") as folder:
        directory = Path(folder)
        store = directory / "events.db"
        until = time.time() - time.time() % STEP_S
        since = until - settings.days * 86400
        started = time.monotonic()
        result.rows = await asyncio.to_thread(fill_history, store, since, until)
        result.fill_s = time.monotonic() - started
        result.store_mb = store.stat().st_size / 1e6
        link = directory / "ttyRS485"
        simulate = ["--link", str(link), "--baud", str(BAUDRATE), "--parity", "N"]
        launched = launch_simulator([*simulate, "--address", "1", "--address", "2"])
        gateway: Gateway | None = None
        try:
            await asyncio.to_thread(simulator_started, launched)
            config = _gateway_config(link, store, settings)
            gateway = Gateway(config, directory)
            gateway.start()
            await asyncio.to_thread(gateway.wait_listening)
            assert gateway.process is not None
            console = f"http://127.0.0.1:{config['console']['port']}"
            await asyncio.to_thread(wait_listening, config["console"]["port"], gateway.process)
            await _measure(settings, gateway, console, since, until, result)
        finally:
            if gateway is not None:
                result.gateway_log = gateway.log_tail()
                await asyncio.to_thread(gateway.stop)
            await asyncio.to_thread(stop_process, launched)
    return result


def fill_history(path: Path, since: float, until: float) -> int:
    """`path` a store holding each drive's history from `since` to `until` at a point a
    minute: values a GD350 reports, wandering as a plant's do. The rows written."""
    database = EventDatabase(str(path), 2**40, 365 * 86400.0, False, 3650 * 86400.0)
    database.open()
    rng = random.Random(1)
    rows = 0
    try:
        batch: list[HistoryPoint] = []
        at = since
        while at < until:
            batch += [HistoryPoint(drive, at, _values(rng, at)) for drive in DRIVES]
            at += STEP_S
            if len(batch) >= FILL_BATCH or at >= until:
                database.append(Batch(history=batch))
                rows += len(batch)
                batch = []
    finally:
        database.close()
    return rows


def _values(rng: random.Random, at: float) -> dict[str, float | str]:
    running = int(at // 3600) % 3 != 0  # two hours in three
    hertz = 35.0 + rng.uniform(-2, 2) if running else 0.0
    return {
        "output_frequency_hz": round(hertz, 2),
        "set_frequency_hz": 35.0 if running else 0.0,
        "bus_voltage_v": round(540 + rng.uniform(-5, 5), 1),
        "output_voltage_v": round(hertz * 7.6),
        "output_current_a": round(hertz * 0.12 + rng.uniform(0, 0.3), 2),
        "rotation_speed_rpm": round(hertz * 29),
        "output_power_pct": round(hertz * 0.35, 1),
        "output_torque_pct": round(hertz * 0.3, 1),
        "pid_reference_pct": 0.0,
        "pid_feedback_pct": round(rng.uniform(0, 1), 2),
        "input_terminals": 1.0 if running else 0.0,
        "output_terminals": 0.0,
        "fault_code": 0.0,
        "ready": 1.0,
        "state": "running_forward" if running else "stopped",
    }


async def _measure(
    settings: HistoryLoadSettings,
    gateway: Gateway,
    console: str,
    since: float,
    until: float,
    result: HistoryLoadResult,
) -> None:
    await asyncio.sleep(2.0)  # the first polls and the console's first pages are in
    await _phase(settings, gateway, result.unloaded, None)
    window = f"since={_iso(since)}&until={_iso(until)}&points={POINTS}"

    async def charts(stop: asyncio.Event) -> None:
        headers = {"Authorization": f"Bearer {TOKEN}"}
        timeout = aiohttp.ClientTimeout(total=ANSWER_TIMEOUT_S)
        async with aiohttp.ClientSession(headers=headers, timeout=timeout) as session:
            await asyncio.gather(
                *(
                    _chart(
                        session,
                        f"{console}/api/drives/{DRIVES[n % 2]}/history?{window}",
                        stop,
                        result,
                    )
                    for n in range(settings.queries)
                )
            )

    await _phase(settings, gateway, result.loaded, charts)


async def _phase(
    settings: HistoryLoadSettings,
    gateway: Gateway,
    phase: Phase,
    alongside: Any,
) -> None:
    stop = asyncio.Event()
    async with asyncio.TaskGroup() as tasks:
        for unit_id in range(1, settings.readers + 1):
            tasks.create_task(timed_reader(gateway.port, unit_id % 2 + 1, stop, phase))
        tasks.create_task(_rss(gateway, stop, phase))
        if alongside is not None:
            tasks.create_task(alongside(stop))
        await asyncio.sleep(settings.phase_s)
        stop.set()


async def timed_reader(port: int, unit_id: int, stop: asyncio.Event, phase: Phase) -> None:
    """A SCADA client with one read outstanding, timed from send to reply."""
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    pdu = struct.pack(">BHH", 0x03, READ_REGISTER, READ_COUNT)
    tid = 0
    try:
        while not stop.is_set():
            tid = (tid + 1) & 0xFFFF
            sent = time.monotonic()
            writer.write(struct.pack(">HHHB", tid, 0, len(pdu) + 1, unit_id) + pdu)
            try:
                header = await asyncio.wait_for(reader.readexactly(7), REPLY_TIMEOUT_S)
                body = await reader.readexactly(struct.unpack(">H", header[4:6])[0] - 1)
            except (TimeoutError, asyncio.IncompleteReadError, OSError):
                phase.errors += 1
                return
            phase.reads += 1
            if body[0] != 0x03 or header[:2] != struct.pack(">H", tid):
                phase.errors += 1
            else:
                phase.latencies_s.append(time.monotonic() - sent)
    finally:
        writer.close()


async def _rss(gateway: Gateway, stop: asyncio.Event, phase: Phase) -> None:
    while not stop.is_set():
        phase.rss_mb.append(gateway.memory_mb()[0])
        await asyncio.sleep(SAMPLE_S)


async def _chart(
    session: aiohttp.ClientSession, url: str, stop: asyncio.Event, result: HistoryLoadResult
) -> None:
    """One viewer's chart of the whole window, asked again as soon as it is answered (after
    the second a 503 asks it to wait)."""
    while not stop.is_set():
        asked = time.monotonic()
        try:
            async with session.get(url) as response:
                body = await response.read()
                result.answers[response.status] += 1
                if response.status == 200:
                    result.answer_s.append(time.monotonic() - asked)
                    if b'"source": "store"' not in body and b'"source":"store"' not in body:
                        result.failures.append("a history answer did not come from the store")
                elif response.status == 503:
                    await asyncio.sleep(float(response.headers.get("Retry-After", "1")))
                else:
                    result.failures.append(f"history: {response.status} {body[:100]!r}")
        except (aiohttp.ClientError, TimeoutError) as exc:
            result.failures.append(f"history: {exc!r}")


def _iso(at: float) -> str:
    return datetime.fromtimestamp(at, UTC).isoformat().replace("+00:00", "Z")


def _gateway_config(link: Path, store: Path, settings: HistoryLoadSettings) -> dict[str, Any]:
    return {
        "gateway_id": "history-load",
        "modbus_tcp": {"host": "127.0.0.1", "port": free_port()},
        "buses": [{"name": "line1", "port": str(link), "baudrate": BAUDRATE, "parity": "N"}],
        "drives": [
            {"name": name, "bus": "line1", "address": n + 1, "model": "gd350"}
            for n, name in enumerate(DRIVES)
        ],
        "logging": {"level": "warning"},
        "storage": {
            "path": str(store),
            "history_days": max(settings.days + 1, 7),
            "max_mb": 2048,
        },
        "console": {
            "enabled": True,
            "host": "127.0.0.1",
            "port": free_port(),
            "users": [
                {
                    "name": "victor",
                    "password_hash": hash_password(secrets.token_urlsafe(16)),  # token only
                    "role": "viewer",
                    "token_hash": hash_token(TOKEN),
                }
            ],
        },
    }


def problems(result: HistoryLoadResult) -> list[str]:
    idle, loaded = result.unloaded, result.loaded
    found = list(dict.fromkeys(result.failures))[:3]
    grown = loaded.rss_peak_mb - idle.rss_peak_mb
    if grown > MAX_RSS_GROWTH_MB:
        found.append(f"RSS peak {grown:+.1f} MB over idle (at most {MAX_RSS_GROWTH_MB:g})")
    if idle.p99_ms and loaded.p99_ms > idle.p99_ms * (1 + MAX_P99_GROWTH):
        found.append(
            f"Modbus-TCP p99 {loaded.p99_ms:.1f} ms loaded, {idle.p99_ms:.1f} ms unloaded "
            f"(within {MAX_P99_GROWTH:.0%} required)"
        )
    if idle.errors or loaded.errors:
        found.append(f"{idle.errors + loaded.errors} Modbus-TCP reads failed")
    if not result.answers[200]:
        found.append("no history query was answered")
    return found


def table(result: HistoryLoadResult) -> str:
    settings = result.settings
    idle, loaded = result.unloaded, result.loaded
    answers = ", ".join(f"{n} x {status}" for status, n in sorted(result.answers.items()))
    slowest = max(result.answer_s, default=0.0)
    typical = percentile(result.answer_s, 0.5)
    rows = [
        (
            "history kept",
            f"{settings.days:g} days of {len(DRIVES)} drives, {result.rows} points, "
            f"{result.store_mb:.0f} MB (written in {result.fill_s:.0f} s)",
        ),
        (
            "history queries",
            f"{settings.queries} at once for {settings.phase_s:g} s, each the whole window, "
            f"every value, {POINTS} points: {answers or 'none'}",
        ),
        ("answer time", f"median {typical:.2f} s, slowest {slowest:.2f} s"),
        (
            "Modbus-TCP p99",
            f"{idle.p99_ms:.1f} ms unloaded, {loaded.p99_ms:.1f} ms loaded "
            f"({_change(idle.p99_ms, loaded.p99_ms)}; within {MAX_P99_GROWTH:.0%} required)",
        ),
        (
            "Modbus-TCP reads",
            f"{idle.reads} unloaded, {loaded.reads} loaded, {idle.errors + loaded.errors} failed",
        ),
        (
            "gateway RSS",
            f"{idle.rss_peak_mb:.1f} MB idle, {loaded.rss_peak_mb:.1f} MB loaded "
            f"({loaded.rss_peak_mb - idle.rss_peak_mb:+.1f} MB; at most "
            f"+{MAX_RSS_GROWTH_MB:g} required)",
        ),
    ]
    found = problems(result)
    rows.append(("verdict", "pass" if not found else "FAIL: " + "; ".join(found)))
    width = max(len(name) for name, _ in rows)
    title = f"invt-gateway stress --history: {settings.days:g} days, {settings.queries} queries"
    return "\n".join([title, "", *(f"  {name.ljust(width)}  {value}" for name, value in rows)])


def percentile(values: list[float], share: float) -> float:
    """The value `share` of `values` are at or below (0.0 for none)."""
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(share * len(ordered)))] if ordered else 0.0


def _change(before: float, after: float) -> str:
    return f"{(after - before) / before:+.0%}" if before else "-"
