"""`stress --opcua-fuzz N`: N random and malformed messages to the OPC UA endpoint
(`opcua_fuzz`) while SCADA reads over Modbus-TCP: is every door still served, and at its pace?

    1  a simulated line of two drives, the gateway on it with its OPC UA server on (security
       None and Basic256Sha256 offered: the fuzzer reaches the parsing of every message type)
    2  Modbus-TCP clients read for `phase_s` (unloaded: the latency's p99)
    3  the same clients read on while the fuzzer sends its N messages (at least `phase_s`)
    4  a well-formed Hello is answered (ACK), the gateway's log is read

It passes when the loaded p99 stays within `MAX_P99_GROWTH` of the unloaded one, no Modbus-TCP
read failed, the Hello after the fuzz was answered, and the gateway's log holds no traceback,
ERROR or CRITICAL line.
"""

from __future__ import annotations

import asyncio
import tempfile
from collections.abc import Awaitable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

from gateway.instruments.bench.processes import free_port, stop_process
from gateway.instruments.stress.history_load import MAX_P99_GROWTH, Phase, timed_reader
from gateway.instruments.stress.opcua_fuzz import FuzzStats, OpcUaFuzzer, summary
from gateway.instruments.stress.processes import Gateway, launch_simulator, simulator_started

BAUDRATE: Final = 115200
READERS: Final = 2
BAD_LINES: Final = ("Traceback", " ERROR ", " CRITICAL ")


@dataclass(frozen=True, slots=True)
class OpcUaFuzzSettings:
    messages: int = 2000
    phase_s: float = 10.0
    seed: int = 1


@dataclass
class OpcUaFuzzResult:
    settings: OpcUaFuzzSettings
    unloaded: Phase = field(default_factory=Phase)
    loaded: Phase = field(default_factory=Phase)
    fuzz: FuzzStats = field(default_factory=FuzzStats)
    hello_after: str = ""
    bad_lines: list[str] = field(default_factory=list)
    gateway_log: str = ""


async def run_opcua_fuzz(settings: OpcUaFuzzSettings) -> OpcUaFuzzResult:
    result = OpcUaFuzzResult(settings)
    with tempfile.TemporaryDirectory(prefix="invt-opcua-fuzz-") as folder:
        directory = Path(folder)
        link = directory / "ttyRS485"
        simulate = ["--link", str(link), "--baud", str(BAUDRATE), "--parity", "N"]
        launched = launch_simulator([*simulate, "--address", "1", "--address", "2"])
        gateway: Gateway | None = None
        try:
            await asyncio.to_thread(simulator_started, launched)
            config = _gateway_config(link, directory)
            # systemd's name for the state directory, as the unit sets it: the OPC UA server's
            # certificate is made there (the instruments take no configuration model).
            gateway = Gateway(config, directory, {"STATE_DIRECTORY": str(directory)})
            gateway.start()
            await asyncio.to_thread(gateway.wait_listening)
            await asyncio.sleep(2.0)  # the first polls are in
            await _phase(settings, gateway, result.unloaded, None)
            fuzzer = OpcUaFuzzer("127.0.0.1", config["opcua"]["port"], settings.seed)
            await _phase(settings, gateway, result.loaded, fuzzer)
            result.fuzz = fuzzer.stats
            result.hello_after = await fuzzer.hello_answer()
        finally:
            if gateway is not None:
                await asyncio.to_thread(gateway.stop)
                text = gateway.log_file.read_text(errors="replace")
                lines = text.splitlines()
                result.bad_lines = [line for line in lines if any(b in line for b in BAD_LINES)]
                result.gateway_log = gateway.log_tail()
            await asyncio.to_thread(stop_process, launched)
    return result


async def _phase(
    settings: OpcUaFuzzSettings, gateway: Gateway, phase: Phase, fuzzer: OpcUaFuzzer | None
) -> None:
    stop = asyncio.Event()
    async with asyncio.TaskGroup() as tasks:
        for unit_id in range(1, READERS + 1):
            tasks.create_task(timed_reader(gateway.port, unit_id, stop, phase))
        waits: list[Awaitable[object]] = [asyncio.sleep(settings.phase_s)]
        if fuzzer is not None:
            waits.append(fuzzer.run(settings.messages))
        await asyncio.gather(*waits)
        stop.set()


def _gateway_config(link: Path, directory: Path) -> dict[str, Any]:
    return {
        "gateway_id": "opcua-fuzz",
        "modbus_tcp": {"host": "127.0.0.1", "port": free_port()},
        "buses": [{"name": "line1", "port": str(link), "baudrate": BAUDRATE, "parity": "N"}],
        "drives": [
            {"name": "pump1", "bus": "line1", "address": 1},
            {"name": "pump2", "bus": "line1", "address": 2},
        ],
        "storage": {"path": str(directory / "events.db")},
        "opcua": {
            "enabled": True,
            "host": "127.0.0.1",
            "port": free_port(),
            "anonymous": True,
            "security": ["None", "Basic256Sha256_SignAndEncrypt"],
        },
    }


def problems(result: OpcUaFuzzResult) -> list[str]:
    idle, loaded = result.unloaded, result.loaded
    found = [f"the gateway logged: {line}" for line in dict.fromkeys(result.bad_lines)][:3]
    if idle.p99_ms and loaded.p99_ms > idle.p99_ms * (1 + MAX_P99_GROWTH):
        found.append(
            f"Modbus-TCP p99 {loaded.p99_ms:.1f} ms under the fuzz, {idle.p99_ms:.1f} ms "
            f"without (within {MAX_P99_GROWTH:.0%} required)"
        )
    if idle.errors or loaded.errors:
        found.append(f"{idle.errors + loaded.errors} Modbus-TCP reads failed")
    if result.hello_after != "ACK":
        found.append(f"a well-formed Hello after the fuzz got {result.hello_after or 'nothing'}")
    return found


def table(result: OpcUaFuzzResult) -> str:
    idle, loaded = result.unloaded, result.loaded
    rows = [
        ("fuzz", summary(result.fuzz)),
        ("Modbus-TCP without", f"{idle.reads} reads, p99 {idle.p99_ms:.1f} ms"),
        ("Modbus-TCP under fuzz", f"{loaded.reads} reads, p99 {loaded.p99_ms:.1f} ms"),
        ("Hello after the fuzz", result.hello_after or "no answer"),
        ("tracebacks, errors logged", str(len(set(result.bad_lines)))),
    ]
    width = max(len(name) for name, _ in rows)
    lines = [f"invt-gateway stress --opcua-fuzz {result.settings.messages}"]
    lines += [f"  {name:<{width}}  {value}" for name, value in rows]
    verdict = problems(result)
    lines.append("  verdict: " + ("PASS" if not verdict else "FAIL: " + "; ".join(verdict)))
    return "\n".join(lines)
