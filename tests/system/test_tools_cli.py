"""The field tools as a technician runs them: real `invt-gateway` subprocesses against a simulated
line served by `invt-gateway simulate --pty`, and through a running gateway with --via.

The lines use parity N: on this kernel a pty refuses a second tcsetattr asking for PARENB at an
unchanged speed (EINVAL), so a pty opened with parity E can't be opened again with E. A real
serial port has no such limit; the tools open the line once per run, so a test runs several.
"""

from __future__ import annotations

import re
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest

from gateway.exit_codes import EXIT_BROKEN_PIPE
from gateway.instruments.simulator import SimulatedLine
from tests.support import free_port, scan_rows
from tests.support.processes import (
    SimulatorProcess,
    entry_point,
    gateway_process,
    run_cli,
    simulator_process,
)

SIMULATED = {1: "GD350", 7: "GD350", 200: "GD350"}
LINE = ("--baud", "115200", "--parity", "N")


@pytest.fixture(scope="module")
def simulator() -> Iterator[SimulatorProcess]:
    addresses = [arg for address in SIMULATED for arg in ("--address", str(address))]
    with simulator_process(
        *addresses, *LINE, "--model", "gd350", "--fault", "7=35", "--response-delay-ms", "2"
    ) as sim:
        yield sim


def test_scan_finds_exactly_the_simulated_drives_with_one_try_per_silent_address() -> None:
    # The line in this process, whose counters say what reached it: a time bound can't tell a
    # retry from a busy machine.
    with SimulatedLine(list(SIMULATED), baudrate=115200, parity="N", response_delay_ms=2) as line:
        line.inject_fault(7, 35)
        result = run_cli(
            "scan", "--port", line.path, *LINE, "--timeout-ms", "15", "--char-timeout-ms", "5"
        )
        ignored = line.stats["ignored"]
    assert result.returncode == 0, result.stderr
    rows = scan_rows(result.stdout)
    assert {address: cells[0] for address, cells in rows.items()} == SIMULATED
    assert rows[1][1:4] == ["stopped", "none", "communication"]
    assert rows[7][1:3] == ["fault", "STo: maladjustment"]
    assert f"3 drive(s) on {line.path} at 115200 baud 8N1" in result.stdout
    # 247 addresses, 244 of them silent: each costs one short timeout, no retry.
    assert ignored == 244
    # Without a terminal (stderr is a pipe here) the scan still says what it does: a line at
    # the start, one per drive found, and how far it got every 2 s (244 timeouts of 15 ms
    # take at least 3.7 s, so at least one such line).
    progress = result.stderr.splitlines()
    assert progress[0] == f"scan: scanning {line.path} at 115200 baud 8N1: 247 addresses"
    found = [text for text in progress if text.startswith("scan: a drive answers")]
    assert found == [f"scan: a drive answers at address {address}" for address in SIMULATED]
    assert any(re.match(r"scan: \d+ of 247 addresses probed, \d found, ", t) for t in progress)


def test_scan_finding_nothing_says_what_to_check(simulator: SimulatorProcess) -> None:
    result = run_cli("scan", "--port", simulator.path, *LINE, "--addresses", "2-4")
    assert result.returncode == 1
    assert "no drive answered" in result.stderr
    for check in ("P14.01", "P14.02", "termination", "P14.00", "P14.03"):
        assert check in result.stderr


def test_read_prints_values_scaled_with_units_and_decoded(simulator: SimulatorProcess) -> None:
    result = run_cli(
        "read", "--port", simulator.path, *LINE, "--address", "1",
        "P00.11", "2100H", "output_frequency", "identification", "0x0003",
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    assert lines[0].startswith("P00.11  10.0 s  (000BH = 0064H: acceleration time 1")
    assert lines[1].startswith("2100H  3 (stopped)  (2100H = 0003H")
    assert lines[2].startswith("output_frequency  0.00 Hz  (3000H = 0000H")
    assert lines[3].startswith("identification  01A0H (GD350)")
    assert lines[4].startswith("P00.03  50.00 Hz  (0003H = 1388H: max. output frequency")


def test_fault_history_reads_as_fault_names(simulator: SimulatorProcess) -> None:
    result = run_cli("read", "--port", simulator.path, *LINE, "--address", "7", "2102H")
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith("2102H  35 (STo: maladjustment)")


def test_write_then_read_round_trips_with_scaling(simulator: SimulatorProcess) -> None:
    result = run_cli(
        "write", "--port", simulator.path, *LINE, "--address", "200",
        "P00.11=12.5", "frequency_setpoint=25.00", "control_word=stop",
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert result.stdout.splitlines() == [
        "P00.11 <- 12.5 s  (000BH = 007DH): written",
        "frequency_setpoint <- 25.00 Hz  (2001H = 09C4H): written",
        "control_word <- 5 (stop)  (2000H = 0005H): written",
    ]
    result = run_cli("read", "--port", simulator.path, *LINE, "-a", "200", "P00.11", "2001H")
    assert result.returncode == 0, result.stderr
    assert result.stdout.splitlines()[0].startswith("P00.11  12.5 s  (000BH = 007DH")
    assert result.stdout.splitlines()[1].startswith("2001H  25.00 Hz  (2001H = 09C4H")


def test_a_parameter_beyond_the_common_table_is_scaled_by_the_drives_series(
    simulator: SimulatorProcess,
) -> None:
    """P03.12 and P05.02 are in the GD350's series table, not the common one: the series comes
    from 2103H (or --model) and scales, signs and names the values."""
    result = run_cli(
        "write", "--port", simulator.path, *LINE, "--address", "200", "P03.12=-50.0", "P05.02=10"
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.splitlines() == [
        "P03.12 <- -50.0 %  (030CH = FE0CH): written",
        "P05.02 <- 10 (frequency UP)  (0502H = 000AH): written",
    ]
    result = run_cli(
        "read", "--port", simulator.path, *LINE, "-a", "200", "--model", "gd350", "P03.12"
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith("P03.12  -50.0 %  (030CH = FE0CH: Keypad setting torque)")
    result = run_cli("write", "--port", simulator.path, *LINE, "--model", "gd350", "P03.12=x")
    assert result.returncode == 2  # refused before the line is opened
    assert "not a number" in result.stderr


def test_refused_write_names_the_drives_reason(simulator: SimulatorProcess) -> None:
    # Inside the manual's range, above P00.03 (50.00 Hz) that bounds it: only the drive knows.
    result = run_cli("write", "--port", simulator.path, *LINE, "--address", "1", "P00.10=60")
    assert result.returncode == 1
    assert "exception 04H operation failure" in result.stderr
    assert "range" in result.stderr


def test_values_are_taken_as_a_person_writes_them(simulator: SimulatorProcess) -> None:
    """Units, the manual's words for a choice; refused before the wire, saying why: a finer
    value than the register holds (never rounded silently), outside the range with its unit."""
    line = ("--port", simulator.path, *LINE, "--address", "1")
    written = run_cli("write", *line, "P00.11=12.5 s", "frequency_setpoint=25Hz", "P00.01=comm")
    assert written.returncode == 0, written.stderr
    assert "P00.11 <- 12.5 s" in written.stdout
    assert "frequency_setpoint <- 25.00 Hz" in written.stdout
    assert "P00.01 <- 2 (communication)" in written.stdout
    finer = run_cli("write", *line, "P00.11=12.34")
    assert finer.returncode == 2
    assert "steps of 0.1 s" in finer.stderr
    assert "12.3 s and 12.4 s" in finer.stderr
    outside = run_cli("write", *line, "P00.03=700")
    assert outside.returncode == 2
    assert "outside 0.00..630.00 Hz" in outside.stderr
    word = run_cli("write", *line, "P00.01=nowhere")
    assert word.returncode == 2
    assert "0 keypad, 1 terminal, 2 communication" in word.stderr
    # Nothing of the refused writes reached the drive.
    assert run_cli("read", *line, "P00.11").stdout.startswith("P00.11  12.5 s")


def test_silent_address_says_what_to_check(simulator: SimulatorProcess) -> None:
    result = run_cli(
        "read", "--port", simulator.path, *LINE, "--address", "9", "--timeout-ms", "50", "P00.11"
    )
    assert result.returncode == 1
    assert "no answer from" in result.stderr
    for check in ("P14.01", "P14.02", "termination", "P14.00"):
        assert check in result.stderr


def test_bad_names_and_values_are_usage_errors(simulator: SimulatorProcess) -> None:
    result = run_cli("read", "--port", simulator.path, *LINE, "speed_of_light")
    assert result.returncode == 2
    assert "Pxx.yy" in result.stderr
    result = run_cli("write", "--port", simulator.path, *LINE, "P00.11=fast")
    assert result.returncode == 2
    assert "not a number" in result.stderr


def test_missing_port_says_what_to_check() -> None:
    result = run_cli("read", "--port", "/dev/ttyUSB-not-there", "P00.11")
    assert result.returncode == 1
    assert "/dev/serial/by-id" in result.stderr
    assert "dialout" in result.stderr


def test_decode_fault() -> None:
    result = run_cli("decode-fault", "35")
    assert (result.returncode, result.stdout) == (0, "STo: maladjustment\n")
    result = run_cli("decode-fault", "23H", "0", "99")
    assert result.returncode == 1  # 99 is in no table
    assert result.stdout.splitlines() == [
        "35: STo: maladjustment",
        "0: none",
        "99: unknown fault 99",
    ]
    assert run_cli("decode-fault", "abc").returncode == 2


def test_output_cut_short_by_head_ends_quietly() -> None:
    """`invt-gateway decode-fault ... | head -1`: the reader goes after one line; the command
    stops with the shell's code for it, no traceback on the terminal."""
    codes = [str(code) for code in range(70)] * 100  # some 300 kB: more than a pipe holds
    with subprocess.Popen(
        [entry_point(), "decode-fault", *codes],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    ) as command:
        assert command.stdout is not None
        assert command.stderr is not None
        assert command.stdout.readline() == b"0: none\n"
        command.stdout.close()  # as head does once it has its line
        stderr = command.stderr.read()
        assert command.wait(timeout=30) == EXIT_BROKEN_PIPE == 141
    assert stderr == b""


def test_decode_fault_by_the_keypads_short_code() -> None:
    """What an engineer reads off the drive's display: the code comes back with its meaning."""
    result = run_cli("decode-fault", "OC1")
    assert (result.returncode, result.stdout) == (0, "4: OC1: overcurrent while accelerating\n")
    assert run_cli("decode-fault", "out1").stdout == "1: OUt1: inverter unit phase U protection\n"
    # A series' own table: the GD350 family's short codes beyond 36 are known by name too.
    assert run_cli("decode-fault", "--model", "gd350", "STo").stdout.startswith("35: STo")
    unknown = run_cli("decode-fault", "OC9")
    assert unknown.returncode == 2
    assert "keypad's short code" in unknown.stderr


def test_a_models_faults_decode_from_its_own_list_only() -> None:
    """The Goodrive200A manual's P07.27 lists 0-28, 32, 33 and 36: 35 (STo elsewhere) is no
    fault of a GD200A's, and STo is no keypad code of one."""
    result = run_cli("decode-fault", "--model", "gd200a", "35", "33", "36")
    assert result.returncode == 1
    assert result.stdout.splitlines() == [
        "35: unknown fault 35",
        "33: ETH2: short circuit to ground 2",
        "36: LL: electronic underload",
    ]
    assert run_cli("decode-fault", "--model", "gd200a", "STo").returncode == 2
    assert run_cli("decode-fault", "--model", "gd20", "35").stdout == "STo: maladjustment\n"


def test_read_and_write_via_a_running_gateway(tmp_path: Path) -> None:
    tcp_port = free_port()
    with SimulatedLine(addresses=[1], baudrate=115200, parity="N", wire_time=True) as line:
        config = {
            "gateway_id": "tools",
            "modbus_tcp": {"host": "127.0.0.1", "port": tcp_port},
            "buses": [{"name": "line1", "port": line.path, "baudrate": 115200, "parity": "N"}],
            "drives": [{"name": "pump1", "bus": "line1", "address": 1, "unit_id": 21}],
        }
        with gateway_process(config, tmp_path) as gateway:
            gateway.wait_ready()
            via = ("--via", f"tcp://127.0.0.1:{tcp_port}")
            result = run_cli("write", *via, "--address", "21", "P00.11=30.0")
            assert result.returncode == 0, result.stderr
            result = run_cli("read", *via, "--address", "21", "P00.11", "state_word_1")
            assert result.returncode == 0, result.stderr
            assert result.stdout.splitlines()[0].startswith("P00.11  30.0 s")
            assert result.stdout.splitlines()[1].startswith("state_word_1  3 (stopped)")
            # A unit id the gateway doesn't route: its 0AH, explained.
            result = run_cli("read", *via, "--address", "99", "P00.11")
            assert result.returncode == 1
            assert "0AH gateway path unavailable" in result.stderr
            # The line itself is the gateway's: the tool says so instead of fighting for it.
            result = run_cli("read", "--port", line.path, *LINE, "P00.11")
            assert result.returncode == 1
            assert "--via tcp://HOST:PORT" in result.stderr
    result = run_cli("read", "--via", f"tcp://127.0.0.1:{tcp_port}", "P00.11")
    assert result.returncode == 1
    assert "cannot connect to the gateway" in result.stderr


def test_scan_on_an_echoing_bursty_glitching_adapter_names_what_it_saw() -> None:
    # A 2-wire adapter without echo suppression that hands bytes over every 20 ms, behind a
    # transceiver that glitches before each reply: the drives are found all the same (the
    # echo of a loop-back is never taken for a drive's answer), and the scan says what to set.
    adapter = ("--echo", "--burst-ms", "20", "--glitch", "FF")
    with simulator_process("--address", "1", "--address", "3", *LINE, *adapter) as sim:
        result = run_cli("scan", "--port", sim.path, *LINE, "--addresses", "1-5")
    assert result.returncode == 0, result.stderr
    assert sorted(scan_rows(result.stdout)) == [1, 3]
    assert "this adapter echoes what is sent" in result.stdout
    assert "set `echo: true`" in result.stdout
    assert "replies arrive in bursts" in result.stdout
    assert "stray byte(s) came before replies" in result.stdout


def test_every_command_says_what_it_does_in_its_help() -> None:
    """`invt-gateway COMMAND --help` has a description beyond the usage and the options."""
    listed = run_cli("--help").stdout
    commands = [
        line.split()[0]
        for line in listed.split("positional arguments:")[1].splitlines()
        if line.startswith("    ") and not line.startswith("      ") and line.split()
    ]
    assert {"run", "check-config", "hash-password", "scan", "params"} <= set(commands)
    for command in commands:
        text = run_cli(command, "--help").stdout
        between = text.split("\n\n")[1]  # after the usage: the description, or the options
        assert not between.startswith(("options:", "positional arguments:")), command
        assert len(between.split()) >= 8, (command, between)


def test_check_config_warns_of_a_serial_device_that_is_not_there(tmp_path: Path) -> None:
    config = tmp_path / "gateway.yaml"
    config.write_text(
        "buses:\n  - name: line1\n    port: /dev/ttyUSB-not-here-42\n"
        "drives:\n  - name: pump1\n    bus: line1\n    address: 1\n"
    )
    result = run_cli("check-config", "--config", str(config))
    assert result.returncode == 0  # valid: the file may be checked away from the box
    assert "valid" in result.stdout
    assert "buses[0].port: /dev/ttyUSB-not-here-42 does not exist" in result.stderr
    present = config.read_text().replace("/dev/ttyUSB-not-here-42", "/dev/null")
    config.write_text(present)
    assert "warning" not in run_cli("check-config", "--config", str(config)).stderr


def test_version_names_the_release_and_the_commit_of_a_checkout(tmp_path: Path) -> None:
    from gateway import __version__
    from gateway.version import checkout_commit

    result = run_cli("--version")
    assert result.returncode == 0
    root = Path(__file__).resolve().parents[2]
    if (root / ".git").exists():  # the suite runs from a checkout, as CI's clone is
        head = subprocess.run(
            ["git", "-C", str(root), "rev-parse", "--short", "HEAD"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
        assert result.stdout == f"invt-gateway {__version__} (commit {head})\n"
    else:
        assert result.stdout == f"invt-gateway {__version__}\n"
    # An installed release has no checkout beside its package: the release alone.
    package = tmp_path / "site-packages" / "gateway"
    package.mkdir(parents=True)
    assert checkout_commit(package) is None
