"""`invt-gateway params backup|diff|restore` as a technician replacing a drive runs them: real
subprocesses against simulated drives on a pty (parity N: see test_tools_cli), and through a
running gateway with --via."""

from __future__ import annotations

import re
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import yaml

from gateway.instruments.simulator import SimulatedLine
from gateway.profile import Parameter
from tests.support import free_port
from tests.support.processes import SimulatorProcess, gateway_process, run_cli, simulator_process

LINE = ("--baud", "115200", "--parity", "N")


@pytest.fixture
def line() -> Iterator[SimulatorProcess]:
    with simulator_process(
        "--drive", "1=gd350a", "--drive", "2=gd350a", "--drive", "3=gd30", *LINE,
        "--response-delay-ms", "1",
    ) as sim:  # fmt: skip
        yield sim


def params(sim: SimulatorProcess, *args: str) -> tuple[int, str, str]:
    result = run_cli("params", *args, "--port", sim.path, *LINE)
    return result.returncode, result.stdout, result.stderr


def test_backup_change_by_hand_restore_then_no_difference(
    line: SimulatorProcess, tmp_path: Path
) -> None:
    backup = tmp_path / "hoist.yaml"
    code, out, err = params(line, "backup", str(backup), "--address", "1")
    assert code == 0, err
    saved = yaml.safe_load(backup.read_text())
    assert (saved["model"], saved["identification"], saved["address"]) == ("gd350a", "01A2H", 1)
    assert saved["parameters"]["P00"]["P00.11"] == {
        "value": 10.0,
        "unit": "s",
        "description": "acceleration time 1",
    }
    assert "P07.27" not in saved["parameters"]["P07"]  # the fault history is read-only
    assert "P17" not in saved["parameters"]  # so is the monitoring group
    assert "P00.18" not in saved["parameters"]["P00"]  # a command (restore the defaults)
    assert "P14.00" not in saved["parameters"]["P14"]  # the line's own settings stay put

    changed = run_cli(
        "write", "--port", line.path, *LINE, "--address", "2", "P00.11=25.0", "P14.03=20",
        "P00.03=60.00",
    )  # fmt: skip
    assert changed.returncode == 0, changed.stderr
    code, out, err = params(line, "diff", str(backup), "--address", "2")
    assert code == 1
    assert out.splitlines() == [
        "P00.03  max. output frequency: drive 60.00 Hz, file 50.00 Hz",
        "P00.11  acceleration time 1: drive 25.0 s, file 10.0 s",
        "P14.03  communication response delay: drive 20 ms, file 5 ms",
    ]

    code, out, err = params(line, "restore", str(backup), "--address", "2")
    assert code == 0, err
    assert "dry run: 3 parameter(s) to write; --apply writes them" in out
    assert params(line, "diff", str(backup), "--address", "2")[0] == 1  # nothing written

    code, out, err = params(line, "restore", str(backup), "--address", "2", "--apply")
    assert code == 0, err
    assert "P00.11 <- 10.0 s" in out
    assert "3 parameter(s) written" in out

    code, out, err = params(line, "diff", str(backup), "--address", "2")
    assert (code, out) == (0, "")
    assert "0 difference(s)" in err


def test_restore_refuses_a_running_drive_then_skips_and_stops_at_the_first_exception(
    line: SimulatorProcess, tmp_path: Path
) -> None:
    backup = tmp_path / "drive1.yaml"
    assert params(line, "backup", str(backup), "--address", "1")[0] == 0
    document = yaml.safe_load(backup.read_text())
    document["parameters"]["P00"]["P00.00"]["value"] = 1  # "◎": locked while running
    document["parameters"]["P00"]["P00.04"]["value"] = 55.0  # above P00.03 = 50 Hz: refused
    document["parameters"]["P00"]["P00.12"]["value"] = 30.0
    document["parameters"]["P00"]["P00.18"] = {"value": 1}  # restore the defaults: never
    document["parameters"]["P07"]["P07.21"] = {"value": 0x1234}  # another drive's bar code
    backup.write_text(yaml.safe_dump(document, sort_keys=False))
    started = run_cli("write", "--port", line.path, *LINE, "--address", "2", "2000H=run_forward")
    assert started.returncode == 0, started.stderr

    code, out, err = params(line, "restore", str(backup), "--address", "2")
    assert code == 0, err  # a dry run says what --apply would do, and that it would refuse
    assert (
        "the drive runs (2100H = 1 (running_forward)): --apply refuses until it is stopped" in out
    )
    code, out, err = params(line, "restore", str(backup), "--address", "2", "--apply")
    assert code == 1
    assert (
        "the drive at address 2 runs (2100H = 1 (running_forward)): stop it before a restore; "
        "nothing was written"
    ) in err
    assert " <- " not in out
    code, out, _ = params(line, "diff", str(backup), "--address", "2")
    assert code == 1
    assert "P00.12  deceleration time 1: drive 10.0 s, file 30.0 s" in out

    stopped = run_cli("write", "--port", line.path, *LINE, "--address", "2", "2000H=coast_stop")
    assert stopped.returncode == 0, stopped.stderr
    code, out, err = params(line, "restore", str(backup), "--address", "2", "--apply")
    assert code == 1
    assert "skipped P07.21: set at the factory: the drive's bar code" in out
    assert (
        "skipped P00.18: a command, not a setting: it restores the default values, clears the "
        "fault records or locks the keypad"
    ) in out
    assert "P00.00 <- 1" in out  # stopped, the "◎" code takes its value
    assert "P00.12 <- 30.0 s" in out  # what fits is written before what the drive refuses
    assert "writing P00.04" in err
    assert "04H operation failure" in err
    assert "2 of 3 written before it" in err


def test_a_file_of_another_series_is_refused_and_a_bad_value_named(
    line: SimulatorProcess, tmp_path: Path
) -> None:
    backup = tmp_path / "drive1.yaml"
    assert params(line, "backup", str(backup), "--address", "1")[0] == 0
    code, _, err = params(line, "restore", str(backup), "--address", "3", "--apply")
    assert code == 1
    assert "answers 2103H = 01F0H (GD30)" in err
    assert "is of a GD350A" in err
    document = yaml.safe_load(backup.read_text())
    document["parameters"]["P14"]["P14.03"]["value"] = 500
    backup.write_text(yaml.safe_dump(document))
    code, _, err = params(line, "diff", str(backup), "--address", "1")
    assert code == 2
    assert "parameters.P14.P14.03.value: 500 is outside 0 ms ... 200 ms" in err
    document["parameters"]["P14"]["P14.03"]["value"] = 5
    document["parameters"]["P05"]["P05.10"]["hex"] = "0x0101"  # edited where it only shows
    backup.write_text(yaml.safe_dump(document))
    code, _, err = params(line, "diff", str(backup), "--address", "1")
    assert code == 2
    assert "parameters.P05.P05.10.hex: 0x0101 is not value 0: edit value (hex only shows it)" in err


def test_diff_through_a_running_gateway(tmp_path: Path) -> None:
    tcp_port = free_port()
    with SimulatedLine(addresses=[1], model="gd300l", baudrate=115200, parity="N") as sim:
        backup = tmp_path / "lift.yaml"
        result = run_cli(
            "params", "backup", str(backup), "--model", "gd300l", "--port", sim.path, *LINE
        )
        assert result.returncode == 0, result.stderr
        assert yaml.safe_load(backup.read_text())["series"] == "GD300-LIFT"
        config = {
            "gateway_id": "params",
            "modbus_tcp": {"host": "127.0.0.1", "port": tcp_port},
            "buses": [{"name": "line1", "port": sim.path, "baudrate": 115200, "parity": "N"}],
            "drives": [
                {"name": "lift1", "bus": "line1", "address": 1, "unit_id": 21, "model": "gd300l"}
            ],
        }
        with gateway_process(config, tmp_path) as gateway:
            gateway.wait_ready()
            via = ("--via", f"tcp://127.0.0.1:{tcp_port}", "--address", "21")
            result = run_cli("write", *via, "P00.12=40.0")
            assert result.returncode == 0, result.stderr
            result = run_cli("params", "diff", str(backup), *via)
            assert result.returncode == 1
            assert result.stdout == ("P00.12  deceleration time 1: drive 40.0 s, file 10.0 s\n")


def test_backup_of_a_gd350_holds_every_writable_parameter_of_its_table(tmp_path: Path) -> None:
    """The figure the README quotes: how many parameters, how long, at 19200 baud."""
    from gateway.profile import get_profile
    from gateway.tools.params import saved_parameters

    wanted = {spec.name for spec in saved_parameters(get_profile("gd350"))}
    backup = tmp_path / "gd350.yaml"
    with simulator_process("--drive", "1=gd350", "--baud", "19200", "--parity", "N") as sim:
        result = run_cli(
            "params", "backup", str(backup), "--address", "1",
            "--port", sim.path, "--baud", "19200", "--parity", "N",
        )  # fmt: skip
    assert result.returncode == 0, result.stderr
    saved = yaml.safe_load(backup.read_text())
    names = {name for group in saved["parameters"].values() for name in group}
    assert names == wanted
    assert len(names) > 300
    assert f"{len(wanted)} parameters of GD350 at address 1" in result.stdout
    assert "unconfirmed for GD350 (another series' table): P00, P01" in result.stderr
    assert "P05" in saved["unconfirmed"]
    assert "absent" not in saved  # the simulated drive serves the whole table
    assert saved["parameters"]["P05"]["P05.01"] == {
        "value": 1,
        "description": "S1 terminal function selection",
        "choice": "forward rotation",
    }
    assert saved["parameters"]["P05"]["P05.10"]["hex"] == "0x0000"
    print(result.stdout.strip())  # the figure: N parameters ... in T s


def test_a_clone_restored_onto_another_drive_leaves_no_difference(
    line: SimulatorProcess, tmp_path: Path
) -> None:
    changes = (
        "P00.11=25.0", "P00.03=60.00", "P00.04=55.00",
        "P02.01=0x004B",  # rated power 7.5 kW: written first, it resets the motor's data
        "P02.05=0x0064",  # rated current 10.0 A
        "P02.03=1450",  # rated speed: the replacement holds it already (below)
        "P03.12=0xFE0C",  # keypad torque -50.0 %: a signed value
        "P05.10=0x0101",  # input polarity: a bit mask
        "P05.02=0x000A",  # S2 = frequency UP
        "P10.02=0xFC18",  # multi-step speed 0: -100.0 %
        "P24.03=0x0FA0",  # hibernation start 40.00 Hz
        "P14.03=20",  # response delay: the communication group goes last
    )  # fmt: skip
    changed = run_cli("write", "--port", line.path, *LINE, "--address", "1", *changes)
    assert changed.returncode == 0, changed.stderr
    same = run_cli("write", "--port", line.path, *LINE, "--address", "2", "P02.03=1450")
    assert same.returncode == 0, same.stderr
    backup = tmp_path / "donor.yaml"
    assert params(line, "backup", str(backup), "--address", "1")[0] == 0
    saved = yaml.safe_load(backup.read_text())["parameters"]
    assert saved["P03"]["P03.12"]["value"] == -50.0
    assert saved["P05"]["P05.02"]["choice"] == "frequency UP"

    code, out, err = params(line, "diff", str(backup), "--address", "2")
    assert code == 1
    assert len(out.splitlines()) == len(changes) - 1  # P02.03 matches already

    code, out, err = params(line, "restore", str(backup), "--address", "2", "--apply")
    assert code == 0, err
    lines = out.splitlines()
    assert lines.index("P02.01 <- 7.5 kW") < lines.index("P02.05 <- 10.0 A")
    assert lines.index("P00.03 <- 60.00 Hz") < lines.index("P00.04 <- 55.00 Hz")
    # P02.01 re-initialises P02.02-P02.10 on the drive: those the file holds go again after it,
    # where they matched before too (P02.03's 1450 rpm would be lost otherwise).
    assert lines.index("P02.01 <- 7.5 kW") < lines.index("P02.03 <- 1450 rpm")
    assert "19 parameter(s) written" in out
    assert [line for line in lines if " <- " in line][-1] == "P14.03 <- 20 ms"
    assert "read back" not in out

    code, out, err = params(line, "diff", str(backup), "--address", "2")
    assert (code, out) == (0, "")


def test_an_old_eighteen_parameter_backup_still_restores(
    line: SimulatorProcess, tmp_path: Path
) -> None:
    """A file `params backup` wrote before the series tables: the common table's 18 codes.
    (P00.07 at 2, the factory's value in the Goodrive200A manual the series borrows: the common
    table's 15 had no source and is gone.)"""
    old = {
        "P00": {
            "P00.00": 2, "P00.01": 2, "P00.02": 0, "P00.03": 50.0, "P00.04": 45.0,
            "P00.05": 0.0, "P00.06": 8, "P00.07": 2, "P00.10": 50.0, "P00.11": 12.5,
            "P00.12": 10.0, "P00.13": 0,
        },
        "P01": {"P01.20": 0.0},
        "P08": {"P08.06": 5.0, "P08.07": 10.0, "P08.08": 10.0},
        "P14": {"P14.03": 5, "P14.04": 0.0},
    }  # fmt: skip
    document = {
        "model": "gd350a",
        "series": "GD350A",
        "identification": "01A2H",
        "address": 1,
        "saved": "2026-01-05T08:00:00Z",
        "parameters": {
            group: {name: {"value": value} for name, value in entries.items()}
            for group, entries in old.items()
        },
    }
    assert sum(len(entries) for entries in old.values()) == 18
    backup = tmp_path / "old.yaml"
    backup.write_text(yaml.safe_dump(document, sort_keys=False))
    code, out, err = params(line, "restore", str(backup), "--address", "2", "--apply")
    assert code == 0, err
    assert "2 parameter(s) written" in out  # P00.04 and P00.11 differ from the factory's
    code, out, err = params(line, "diff", str(backup), "--address", "2")
    assert (code, out) == (0, "")
    assert "0 difference(s) in 18 parameters" in err


def test_diff_and_restore_from_another_drive_on_the_line(line: SimulatorProcess) -> None:
    """A clone without a file: drive 1 is the donor, drive 2 the replacement."""
    changed = run_cli(
        "write", "--port", line.path, *LINE, "--address", "1", "P00.12=40.0", "P05.02=0x000A"
    )
    assert changed.returncode == 0, changed.stderr
    clone = ("--from-address", "1", "--address", "2", "--port", line.path, *LINE)
    result = run_cli("params", "diff", *clone)
    assert result.returncode == 1
    assert result.stdout.splitlines() == [
        "P00.12  deceleration time 1: drive 10.0 s, file 40.0 s",
        "P05.02  S2 terminal function selection: drive 4 (forward jogging), file 10 (frequency UP)",
    ]
    result = run_cli("params", "restore", *clone, "--apply")
    assert result.returncode == 0, result.stderr
    result = run_cli("params", "diff", *clone)
    assert (result.returncode, result.stdout) == (0, "")
    both = run_cli("params", "diff", "x.yaml", *clone)
    assert (both.returncode, both.stderr.strip()) == (
        2,
        "invt-gateway params: give either FILE or --from-address N",
    )


def test_an_unconfirmed_code_the_drive_lacks_is_listed_not_fatal() -> None:
    """Another series' table may name a code this drive lacks: it answers 02H for it."""
    from gateway.errors import FieldError
    from gateway.profile import Parameter, get_profile
    from gateway.tools.masters import RtuMaster, SerialOptions
    from gateway.tools.params import read_parameters

    table = get_profile("gd350").parameter_table
    borrowed = [row for row in table.rows if row.group == "P13"]  # P13.13-P13.15, unconfirmed
    missing = Parameter("P13.16", "not on this drive", confirmed=False)
    with SimulatedLine(addresses=[1], model="gd350", baudrate=115200, parity="N") as sim:
        master = RtuMaster(SerialOptions(sim.path, 115200, "N"))
        try:
            absent: list[str] = []
            values = read_parameters(master, 1, [*borrowed, missing], absent=absent)
            assert (sorted(values), absent) == (["P13.13", "P13.14", "P13.15"], ["P13.16"])
            confirmed = Parameter("P13.16", "not on this drive")
            with pytest.raises(FieldError, match=r"reading P13\.16 at 1: exception 02H"):
                read_parameters(master, 1, [*borrowed, confirmed], absent=[])
        finally:
            master.close()


def _another_value(spec: Parameter, raw: int) -> int | None:
    """A value other than `raw` within the spec's own range, or None where changing it would
    also move another parameter's range (the bounds), the line's settings (P14: the restore
    must keep talking) or where the range holds one value."""
    if spec.minimum_from or spec.maximum_from or spec.group == "P14":
        return None
    number = spec.number(raw)
    other = spec.minimum if number != spec.minimum else spec.minimum + 1
    return spec.word(other) if other <= spec.maximum else None


def _written(out: str) -> int:
    found = re.search(r"^(\d+) parameter\(s\) written and verified in ", out, re.MULTILINE)
    assert found is not None, out
    return int(found[1])


def test_a_whole_drive_cloned_at_19200_baud_leaves_no_difference(
    tmp_path: Path, record_property: Callable[[str, object], None]
) -> None:
    """The figure the README quotes: a replacement drive given every parameter of the failed
    one, at the baud rate most plants run, written and read back one by one."""
    from gateway.profile import get_profile
    from gateway.tools.params import saved_parameters

    slow = ("--baud", "19200", "--parity", "N")
    profile = get_profile("gd350a")
    bounds = {
        name for spec in profile.parameters for name in (spec.minimum_from, spec.maximum_from)
    }
    with simulator_process("--drive", "1=gd350a", "--drive", "2=gd350a", *slow) as sim:
        factory = tmp_path / "factory.yaml"

        def run(*args: str) -> tuple[int, str, str, float]:
            started = time.monotonic()
            result = run_cli("params", *args, "--port", sim.path, *slow, timeout_s=300)
            return result.returncode, result.stdout, result.stderr, time.monotonic() - started

        code, out, err, backup_s = run("backup", str(factory), "--address", "1")
        assert code == 0, err
        # The donor: every parameter it can hold otherwise set otherwise than the factory did.
        document = yaml.safe_load(factory.read_text())
        specs = {spec.name: spec for spec in saved_parameters(profile)}
        changed = 0
        for entries in document["parameters"].values():
            for name, entry in entries.items():
                spec = specs[name]
                raw = spec.word(round(entry["value"] * 10**spec.decimals))
                other = None if name in bounds else _another_value(spec, raw)
                if other is not None:
                    entries[name] = {"value": spec.number(other) / 10**spec.decimals}
                    changed += 1
        donor_settings = tmp_path / "donor-settings.yaml"
        donor_settings.write_text(yaml.safe_dump(document, sort_keys=False))
        code, out, err, _ = run("restore", str(donor_settings), "--address", "1", "--apply")
        assert code == 0, err
        assert _written(out) >= changed  # and those P02.01 re-initialised, written again

        donor = tmp_path / "donor.yaml"
        code, out, err, _ = run("backup", str(donor), "--address", "1")
        assert code == 0, err
        saved = len(specs)
        assert f"{saved} parameters of GD350A at address 1" in out
        code, out, err, _ = run("diff", str(donor), "--address", "2")
        assert code == 1
        assert len(out.splitlines()) == changed

        code, out, err, restore_s = run("restore", str(donor), "--address", "2", "--apply")
        assert code == 0, err
        written = _written(out)
        assert written >= changed
        assert "read back" not in out
        code, out, err, _ = run("diff", str(donor), "--address", "2")
        assert (code, out) == (0, ""), out
        assert f"0 difference(s) in {saved} parameters" in err
        result = run_cli(
            "params", "diff", "--from-address", "1", "--address", "2", "--port", sim.path, *slow
        )
        assert (result.returncode, result.stdout) == (0, "")
    figure = (
        f"GD350A at 19200 baud 8N1: backup of {saved} parameters in {backup_s:.1f} s; "
        f"restore of the {changed} that differ ({written} writes, each read back, then all "
        f"{saved} read back) in {restore_s:.1f} s; diff afterwards empty"
    )
    record_property("figure:params clone", figure)
    print(figure)
