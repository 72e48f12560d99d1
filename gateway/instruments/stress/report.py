"""The stress run's table, its JSON document, and the verdict.

The run passes when no client ever received a wrong value (nor the hostile client an answer to
something it didn't send), fewer than 0.1 % of the requests
outside the outages were errors, every outage recovered, and the gateway's memory did not grow
(the end within 10 % plus 2 MB of the start: a short run's allocator noise is no leak).
"""

from __future__ import annotations

from typing import Any, Final

from gateway.instruments.stress.scenario import RECOVERY_LIMIT_S, StressResult

MAX_ERROR_RATE: Final = 0.001
MEMORY_GROWTH_SHARE: Final = 0.10
MEMORY_GROWTH_SLACK_MB: Final = 2.0


def problems(result: StressResult) -> list[str]:
    found = []
    if result.load.wrong:
        found.append(f"{result.load.wrong} wrong values: {result.load.wrong_examples[:3]}")
    if result.error_rate >= MAX_ERROR_RATE and not result.settings.late_beyond_drain:
        found.append(f"error rate {result.error_rate:.3%} is not below {MAX_ERROR_RATE:.1%}")
    if result.hostile.wrong:
        found.append(f"hostile client: {result.hostile.examples[:3]}")
    if result.steady_requests == 0:
        found.append("no request was answered")
    for recovery in result.recoveries:
        if recovery.seconds is None:
            found.append(f"{recovery.what} not back within {RECOVERY_LIMIT_S:.0f} s")
    limit = result.memory_start_mb * (1 + MEMORY_GROWTH_SHARE) + MEMORY_GROWTH_SLACK_MB
    if result.memory_start_mb and result.memory_end_mb > limit:
        found.append(
            f"memory grew from {result.memory_start_mb:.1f} to {result.memory_end_mb:.1f} MB"
        )
    return found


def table(result: StressResult) -> str:
    settings = result.settings
    load = result.load
    hostile = result.hostile
    outage_requests = sum(load.requests.values()) - result.steady_requests
    outage_errors = sum(load.errors.values()) - result.steady_errors
    frames = result.frames or 1
    kinds = ", ".join(f"{kind} {count}" for kind, count in result.faults_by_kind.items())
    growth = result.memory_end_mb - result.memory_start_mb
    share = growth / result.memory_start_mb if result.memory_start_mb else 0.0
    required = (
        "not judged: late replies outlast the response timeout and drain"
        if settings.late_beyond_drain
        else f"below {MAX_ERROR_RATE:.1%} required"
    )
    rows = [
        ("frames tried (on the line)", f"{result.frames}"),
        (
            "faults injected",
            f"{result.faults_injected} ({result.faults_injected / frames:.1%} of frames): {kinds}",
        ),
        (
            "client requests",
            f"{result.steady_requests} steady, {outage_requests} during outages",
        ),
        (
            "errors seen by clients",
            f"{result.steady_errors} ({result.error_rate:.3%} of steady requests, {required}); "
            f"{outage_errors} during outages",
        ),
        ("wrong values", f"{load.wrong} (must be 0)"),
        (
            "hostile Modbus-TCP input",
            f"{hostile.frames} random frames ({hostile.malformed} malformed headers) on "
            f"{hostile.connections} connections; {hostile.answers} answers, "
            f"{hostile.wrong} not its own (must be 0)",
        ),
    ]
    for recovery in result.recoveries:
        seconds = "NOT BACK" if recovery.seconds is None else f"{recovery.seconds:.2f} s"
        rows.append((f"recovery: {recovery.what}", f"{seconds} after {recovery.measured_from}"))
    if not result.broker:
        rows.append(("recovery: MQTT broker", "not run: mosquitto is not installed"))
    rows.append(
        (
            "gateway memory (RSS)",
            f"{result.memory_start_mb:.1f} MB at start, {result.memory_end_mb:.1f} MB at end "
            f"({share:+.1%}), peak {result.memory_peak_mb:.1f} MB",
        )
    )
    found = problems(result)
    rows.append(("verdict", "pass" if not found else "FAIL: " + "; ".join(found)))
    width = max(len(name) for name, _ in rows)
    title = (
        f"invt-gateway stress: {result.elapsed_s:.0f} s, {settings.fault_rate:.1%} line faults, "
        f"{settings.clients} clients on {settings.drives} drives at {settings.baudrate} baud"
    )
    return "\n".join([title, "", *(f"  {name.ljust(width)}  {value}" for name, value in rows)])


def document(result: StressResult) -> dict[str, Any]:
    settings = result.settings
    load = result.load
    return {
        "settings": {
            "duration_s": settings.duration_s,
            "fault_rate": settings.fault_rate,
            "clients": settings.clients,
            "drives": settings.drives,
            "baudrate": settings.baudrate,
            "seed": settings.seed,
            "late_ms": list(settings.late_ms),
            "slow_drive_ms": None
            if settings.slow_drive_ms is None
            else list(settings.slow_drive_ms),
        },
        "elapsed_s": round(result.elapsed_s, 3),
        "frames": result.frames,
        "faults_injected": result.faults_injected,
        "faults_by_kind": result.faults_by_kind,
        "requests": dict(load.requests),
        "errors": dict(load.errors),
        "error_rate": result.error_rate,
        "exceptions": {f"{code:02X}": count for code, count in sorted(load.exceptions.items())},
        "answered": load.answered,
        "wrong": load.wrong,
        "wrong_examples": load.wrong_examples,
        "hostile": {
            "frames": result.hostile.frames,
            "malformed": result.hostile.malformed,
            "connections": result.hostile.connections,
            "closed_by_gateway": result.hostile.closed_by_gateway,
            "answers": result.hostile.answers,
            "wrong": result.hostile.wrong,
            "examples": result.hostile.examples,
        },
        "recoveries": [
            {"what": r.what, "measured_from": r.measured_from, "seconds": r.seconds}
            for r in result.recoveries
        ],
        "broker": result.broker,
        "memory_mb": {
            "start": round(result.memory_start_mb, 2),
            "end": round(result.memory_end_mb, 2),
            "peak": round(result.memory_peak_mb, 2),
        },
        "problems": problems(result),
        "passed": not problems(result),
    }
