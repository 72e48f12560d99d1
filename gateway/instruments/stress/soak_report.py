"""The soak's table: the gateway's samples over time, what each kind of user saw, the memory's
growth after the warm-up, and the verdict.

The run passes when no value was wrong, no call failed that a fault doesn't explain, the
gateway ran to the end, and (on a run whose measured part is long enough to tell) its resident
memory grew at most `MAX_GROWTH_MB_PER_HOUR` after the warm-up: the slope of a least-squares
line through the samples, so one sample's noise moves it little.
"""

from __future__ import annotations

from typing import Final

from gateway.instruments.stress.checked_load import STEADY
from gateway.instruments.stress.soak import MIN_JUDGED_S, Sample, SoakResult
from gateway.progress import duration_text

MAX_GROWTH_MB_PER_HOUR: Final = 1.0


def growth_mb_per_hour(result: SoakResult) -> float | None:
    """The RSS slope after the warm-up; None when that part is shorter than `MIN_JUDGED_S`."""
    warm = [s for s in result.samples if s.at_s >= result.settings.warm_up_s]
    if len(warm) < 3 or warm[-1].at_s - warm[0].at_s < MIN_JUDGED_S:
        return None
    return _slope([s.at_s / 3600 for s in warm], [s.rss_mb for s in warm])


def problems(result: SoakResult) -> list[str]:
    load = result.load
    found = []
    if load.wrong:
        found.append(f"{load.wrong} wrong values: {load.wrong_examples[:3]}")
    if load.errors[STEADY]:
        found.append(f"{load.errors[STEADY]} Modbus-TCP errors outside a stalled drive")
    if not load.requests[STEADY]:
        found.append("no Modbus-TCP request was answered")
    users = (("MQTT", result.mqtt), ("console", result.console), ("brief SCADA", result.brief))
    for what, stats in users:
        if stats.errors:
            found.append(f"{stats.errors} {what} errors: {stats.examples[:2]}")
    if result.scrapes.errors:
        found.append(f"{result.scrapes.errors} scrapes failed: {result.scrapes.examples[:2]}")
    if result.gateway_exit is not None:
        found.append(f"the gateway ended with exit code {result.gateway_exit}")
    growth = growth_mb_per_hour(result)
    if growth is not None and growth > MAX_GROWTH_MB_PER_HOUR:
        found.append(f"RSS grew {growth:+.2f} MB/hour after the warm-up")
    return found


def table(result: SoakResult) -> str:
    settings = result.settings
    lines = [
        f"invt-gateway stress --soak {settings.hours:g}: {duration_text(result.elapsed_s)}, "
        f"rounds of {duration_text(settings.round_s)}, warm-up {duration_text(settings.warm_up_s)}",
        "RSS: the lowest of each interval, read every second; CPU: the gateway's, per bus "
        "transaction",
        "",
        "  time       RSS MB  open files  CPU/transaction  transactions",
    ]
    previous: Sample | None = None
    for sample in result.samples:
        lines.append(
            f"  {sample.at_s / 60:6.1f} min  {sample.rss_mb:6.1f}  {sample.open_files:10d}  "
            f"{_cpu_per_transaction(previous, sample):>15}  {sample.transactions:12d}"
        )
        previous = sample
    lines += ["", *(f"  {name.ljust(26)}  {value}" for name, value in _rows(result))]
    return "\n".join(lines)


def _rows(result: SoakResult) -> list[tuple[str, str]]:
    load = result.load
    excused_modbus = sum(load.errors.values()) - load.errors[STEADY]
    rows = [
        (
            "Modbus-TCP requests",
            f"{sum(load.requests.values())}, {load.errors[STEADY]} errors, "
            f"{excused_modbus} while a drive stalled",
        ),
        ("wrong values", f"{load.wrong} (must be 0)"),
        ("reads on a new connection", f"{result.brief.calls}, {result.brief.errors} errors"),
        (
            "MQTT commands",
            f"{result.mqtt.calls}, {result.mqtt.errors} errors, "
            f"{result.mqtt.excused} while the broker was away or a drive stalled",
        ),
        ("console calls", f"{result.console.calls}, {result.console.errors} errors"),
        ("scrapes", f"{result.scrapes.calls}, {result.scrapes.errors} errors"),
        ("faults", ", ".join(f"{what} {n}" for what, n in result.faults.items()) or "none"),
    ]
    rows += [(what, f"not run: {why}") for what, why in result.left_out.items()]
    rows.append(("RSS after the warm-up", _growth_text(result)))
    rows += [
        (
            "grew most (tracemalloc)" if index == 0 else "",
            f"{g.grown_kb:+9.1f} kB {g.blocks:+7d} blocks  {g.where}"
            + (f"  (from {g.caller})" if g.caller and g.caller != g.where else ""),
        )
        for index, g in enumerate(result.growth)
    ]
    found = problems(result)
    rows.append(("verdict", "pass" if not found else "FAIL: " + "; ".join(found)))
    return rows


def _growth_text(result: SoakResult) -> str:
    warm = [s for s in result.samples if s.at_s >= result.settings.warm_up_s]
    if not warm:
        return "no sample after the warm-up"
    span = f"{warm[0].rss_mb:.1f} -> {warm[-1].rss_mb:.1f} MB"
    growth = growth_mb_per_hour(result)
    if growth is None:
        return f"{span}; not judged: less than {duration_text(MIN_JUDGED_S)} after the warm-up"
    return f"{span}: {growth:+.2f} MB/hour (at most {MAX_GROWTH_MB_PER_HOUR:g} required)"


def _cpu_per_transaction(previous: Sample | None, sample: Sample) -> str:
    before = previous or Sample(0.0, 0.0, 0, sample.cpu_s, 0)
    transactions = sample.transactions - before.transactions
    if previous is None or transactions <= 0:
        return "-"
    return f"{(sample.cpu_s - before.cpu_s) / transactions * 1e6:.0f} us"


def _slope(xs: list[float], ys: list[float]) -> float:
    mean_x = sum(xs) / len(xs)
    mean_y = sum(ys) / len(ys)
    spread = sum((x - mean_x) ** 2 for x in xs)
    return sum((x - mean_x) * (y - mean_y) for x, y in zip(xs, ys, strict=True)) / spread
