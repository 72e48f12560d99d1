"""`invt-gateway stress`: a short run of the real command (its subprocesses, line faults, a
killed gateway, an unplugged port, a restarted broker), and its table."""

from __future__ import annotations

import json
import re
import signal
import sys
from collections import Counter

from gateway.instruments.stress.checked_load import STEADY, LoadStats
from gateway.instruments.stress.report import problems, table
from gateway.instruments.stress.scenario import Recovery, StressResult, StressSettings
from tests.support import RecordProperty
from tests.support.processes import assert_ending_leaves_nothing_behind, run_cli


def test_a_short_stress_run_passes_and_reports_every_figure(
    record_property: RecordProperty,
) -> None:
    # Seed 2: its spoilt replies never hit all three attempts of one request in a short run,
    # so the verdict doesn't hang on one unlucky error among a few hundred requests.
    result = run_cli("stress", "--duration", "6", "--seed", "2", "--json", timeout_s=90)
    assert result.returncode == 0, result.stdout + result.stderr
    report = json.loads(result.stdout)
    assert report["passed"], report["problems"]
    assert report["wrong"] == 0
    # Real work was done and checked; how much depends on how busy the machine is (the figure
    # is printed), so the bound is only that it is not a handful.
    assert report["frames"] > 50
    assert report["faults_injected"] > 0
    assert report["requests"][STEADY] > 50
    hostile = report["hostile"]
    assert hostile["frames"] > 100
    assert hostile["malformed"] > 0
    assert hostile["wrong"] == 0
    recoveries = {r["what"]: r["seconds"] for r in report["recoveries"]}
    assert set(recoveries) == {"gateway SIGKILL", "serial port", "MQTT broker"}
    assert all(0 < seconds < 10 for seconds in recoveries.values()), recoveries
    assert 0 < report["memory_mb"]["start"] < 200
    assert "stress: serial port: back" in result.stderr  # progress as it goes
    # Not a terminal: plain lines, each with the overall progress and the expected end.
    assert "\r" not in result.stderr
    events = [line for line in result.stderr.splitlines() if line.startswith("stress: ")]
    assert len(events) >= 4, result.stderr
    assert all(re.search(r"\d+% done, .* ends ~\d\d:\d\d:\d\d \(in ", e) for e in events)
    times = ", ".join(f"{what} {seconds:.2f} s" for what, seconds in recoveries.items())
    record_property(
        "figure:stress 6 s",
        f"{report['frames']} frames, {report['faults_injected']} faults, "
        f"{report['errors'].get(STEADY, 0)} errors in {report['requests'][STEADY]} steady "
        f"requests, {report['wrong']} wrong; {hostile['frames']} hostile frames "
        f"({hostile['malformed']} malformed), {hostile['wrong']} answers not its own; "
        f"recoveries {times}; RSS "
        f"{report['memory_mb']['start']} -> {report['memory_mb']['end']} MB",
    )


def test_the_table_names_each_figure_and_the_verdict() -> None:
    load = LoadStats(
        requests=Counter({STEADY: 10000, "serial port": 50}),
        errors=Counter({STEADY: 3, "serial port": 45}),
        answered=9997,
    )
    result = StressResult(
        StressSettings(duration_s=600),
        elapsed_s=601,
        frames=11000,
        faults_injected=550,
        faults_by_kind={"crc": 100, "late": 90},
        load=load,
        recoveries=[Recovery("serial port", "plugged back in", 0.5)],
        memory_start_mb=40.0,
        memory_end_mb=40.5,
        memory_peak_mb=41.0,
        broker=False,
    )
    text = table(result)
    assert "frames tried (on the line)  11000" in text
    assert "faults injected             550 (5.0% of frames): crc 100, late 90" in text
    assert "3 (0.030% of steady requests" in text
    assert "wrong values                0 (must be 0)" in text
    assert "recovery: serial port       0.50 s after plugged back in" in text
    assert "not run: mosquitto is not installed" in text
    assert text.rstrip().endswith("verdict                     pass")
    grown = StressResult(StressSettings(), load=load, memory_start_mb=40, memory_end_mb=47)
    assert problems(grown) == ["memory grew from 40.0 to 47.0 MB"]


def test_a_stress_run_ended_by_sigterm_leaves_nothing_it_started_behind() -> None:
    """Its gateway, simulated drives and broker stop with it: an orphaned gateway would take
    the next run's line for its own."""
    stress = [sys.executable, "-m", "gateway", "stress", "--duration", "120", "--json"]
    assert_ending_leaves_nothing_behind(stress, children=2)


def test_a_stress_run_killed_by_sigkill_leaves_nothing_it_started_behind() -> None:
    """SIGKILL runs none of its code: its simulated line, broker and gateway end with it all
    the same (the kernel tells them: PR_SET_PDEATHSIG)."""
    stress = [sys.executable, "-m", "gateway", "stress", "--duration", "120", "--json"]
    assert_ending_leaves_nothing_behind(stress, children=3, signum=signal.SIGKILL)


def test_a_short_line_truth_run_stalls_drives_and_checks_every_value() -> None:
    """`stress --line-truth`: late, dropping and stalling drives, two without 08H, on one line:
    its verdict is no wrong value and every drive back within 1 s of each stall."""
    result = run_cli("stress", "--line-truth", "--duration", "15", "--seed", "3", timeout_s=120)
    assert result.returncode == 0, result.stdout + result.stderr
    figures = dict(
        re.split(r"\s{2,}", line.strip(), maxsplit=1)
        for line in result.stdout.splitlines()
        if re.search(r"\S\s{2,}\S", line)
    )
    assert figures["wrong values"] == "0"
    assert int(figures["reads checked"]) > 50
    assert int(figures["stalls"].split()[0]) >= 1
    assert float(figures["back after a stall, slowest"].split()[0]) < 1.0
    assert result.stdout.rstrip().endswith("verdict: PASS")
