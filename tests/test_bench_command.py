"""`invt-gateway bench` as a user runs it: a real subprocess, its JSON checked (figures are the
command's business; here only what must hold on any machine: no wrong value, no t3.5 violation,
a wire maximum computed from the case)."""

from __future__ import annotations

import json
import subprocess
import sys


def test_bench_prints_checked_figures_as_json() -> None:
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "gateway",
            "bench",
            "--baud",
            "115200",
            "--duration",
            "1",
            "--warmup",
            "0.3",
            "--case",
            "2w 8c",
            "--json",
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    names = [row["case"] for row in report["cases"]]
    assert names == [
        "2w 8c",
        "2w 8c same registers",
        "2w 8c one dead of 4",
        "2w 8c same regs, cache",
    ]
    for row in report["cases"]:
        assert row["wrong"] == 0
        assert row["t3.5 viol"] == 0
        assert row["bus tx/s"] > 0
        assert row["client tx/s"] > 0
        assert row["peak RSS MB"] > 0
        # Coalescing answers several clients per transaction: never more CPU per answer.
        assert row["CPU us/ans"] <= row["CPU us/tx"]
        assert 0 <= row["CPU"] < 2  # the gateway's share of the machine's two cores
        # 115200 8E1, 8 + 9 bytes, t3.5 1.75 ms, the drive's 5 ms: 8.37 ms a transaction.
        assert abs(row["wire max/s"] - 1 / (17 * 11 / 115200 + 0.00175 + 0.005)) < 0.1
    assert any("served by coalescing alone" in line for line in report["summary"])
