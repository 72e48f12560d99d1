"""Every drive family of the manuals the product was built from, each with its own fault table.

Goodrive30, IPE300, Goodrive300-LIFT, Goodrive350A and Goodrive350-UL as a user names them in
the config and on the command line; a fault code one series lists and another doesn't.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from gateway.config import parse_config
from gateway.profile import describe_identification, get_profile
from gateway.profile.telemetry import decode_telemetry
from tests.processes import run_cli

FIVE_SERIES = ("gd30", "ipe300", "gd350a", "gd300l", "gd350ul")


@pytest.mark.parametrize(
    ("typed", "key"),
    [
        ("gd30", "gd30"),
        ("GD30", "gd30"),
        ("Goodrive30", "gd30"),
        ("ipe300", "ipe300"),
        ("IPE300", "ipe300"),
        ("gd300l", "gd300l"),
        ("GD300-LIFT", "gd300l"),
        ("gd300lift", "gd300l"),
        ("Goodrive300-LIFT", "gd300l"),
        ("gd350a", "gd350a"),
        ("Goodrive350A", "gd350a"),
        ("gd350ul", "gd350ul"),
        ("GD350-UL", "gd350ul"),
    ],
)
def test_model_names_users_type(typed: str, key: str) -> None:
    assert get_profile(typed).key == key


def test_check_config_accepts_each_model_name(tmp_path: Path) -> None:
    names = ["gd30", "Goodrive30", "ipe300", "gd300l", "GD300-LIFT", "gd350a", "gd350ul"]
    drives = "\n".join(
        f"  - {{name: d{i}, bus: line1, address: {i}, model: {name}}}"
        for i, name in enumerate(names, start=1)
    )
    path = tmp_path / "config.yaml"
    path.write_text(f"buses:\n  - {{name: line1, port: /dev/ttyUSB0}}\ndrives:\n{drives}\n")
    result = subprocess.run(
        [sys.executable, "-m", "gateway", "check-config", "--config", str(path)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 0, result.stderr
    for name in names:
        assert f" {name} " in result.stdout
    path.write_text(
        "buses:\n  - {name: line1, port: /dev/ttyUSB0}\n"
        "drives:\n  - {name: d1, bus: line1, address: 1, model: gd3000}\n"
    )
    result = subprocess.run(
        [sys.executable, "-m", "gateway", "check-config", "--config", str(path)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode != 0
    assert "drives[0] (d1).model" in result.stderr
    assert "gd30, ipe300, gd300l" in result.stderr


def test_each_series_has_its_own_fault_table() -> None:
    # 40 is the GD350 family's STO; a Goodrive30 or a GD20 lists no fault 40.
    assert get_profile("gd350a").faults.describe(40) == "STO"
    assert get_profile("gd350ul").faults.describe(40) == "STO"
    for series in ("gd30", "ipe300", "gd300l", "gd20", "gd300"):
        assert get_profile(series).faults.describe(40) == "unknown fault 40"
        assert get_profile(series).faults.describe(35) == "STo: maladjustment"
    for series in ("gd30", "ipe300", "gd300l"):
        assert not get_profile(series).faults.confirmed
    assert get_profile("gd350a").faults.confirmed


def test_telemetry_names_a_fault_only_from_the_drives_own_table() -> None:
    registers = {0x2100: 4, 0x2101: 0, 0x2102: 40}
    gd350a = decode_telemetry(get_profile("gd350a"), registers)
    gd30 = decode_telemetry(get_profile("gd30"), registers)
    assert (gd350a["fault_name"], gd350a["fault_description"]) == ("STO", "STO")
    assert (gd30["fault_name"], gd30["fault_description"]) == ("40", "unknown fault 40")


def test_identification_names_the_series_as_far_as_the_code_tells() -> None:
    assert describe_identification(0x010A) == "GD300 or GD300-LIFT"
    assert describe_identification(0x01A2) == "GD350A"
    assert describe_identification(0x01A1) == "GD350-UL"
    assert describe_identification(0x01F0) == "GD30 (01F0H unconfirmed)"
    assert describe_identification(0x01F1) == "IPE300 (01F1H unconfirmed)"
    assert describe_identification(0x0150) == "unknown series (0150H)"


def test_a_site_corrects_unconfirmed_facts_in_the_config() -> None:
    config = parse_config(
        """
buses: [{name: line1, port: /dev/ttyUSB0}]
drives:
  - name: lift1
    bus: line1
    address: 1
    model: gd30
    identification: [01E5H]
    faults: {40: "BRK: brake fault", 18: "CE"}
    ready_bit_set_means_ready: false
"""
    )
    profile = config.drives[0].profile()
    assert profile.identification == (0x01E5,)
    assert profile.identification_confirmed
    assert profile.faults.describe(40) == "BRK: brake fault"
    assert profile.faults.describe(18) == "CE"
    assert profile.faults.describe(35) == "STo: maladjustment"
    assert not profile.ready_bit_set_means_ready
    assert get_profile("gd30").faults.describe(40) == "unknown fault 40"  # others untouched


def test_decode_fault_with_a_model_uses_its_table_and_exits_1_for_a_code_it_lacks() -> None:
    result = run_cli("decode-fault", "--model", "gd350a", "40")
    assert (result.returncode, result.stdout) == (0, "STO\n")
    result = run_cli("decode-fault", "--model", "gd30", "40")
    assert (result.returncode, result.stdout) == (1, "unknown fault 40\n")
    assert "unconfirmed" in result.stderr or "no public manual" in result.stderr
    result = run_cli("decode-fault", "--model", "gd300l", "35", "11")
    assert result.returncode == 0
    assert result.stdout.splitlines() == ["35: STo: maladjustment", "11: OL1: motor overload"]
    result = run_cli("decode-fault", "--model", "gd999", "35")
    assert result.returncode == 2
    assert "valid profiles are" in result.stderr
