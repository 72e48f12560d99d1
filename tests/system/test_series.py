"""Every drive family of the manuals the product was built from, each with its own fault table.

Goodrive30, IPE300, Goodrive300-LIFT, Goodrive350A and Goodrive350-UL as a user names them in
the config and on the command line; a fault code one series lists and another doesn't.
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest
import serial

from gateway.config import parse_config
from gateway.instruments.simulator import SimulatedLine
from gateway.profile import InvtProfile, describe_identification, get_profile
from gateway.profile.invt import INVT_PROFILES
from gateway.tools.scan import FoundDrive
from tests.support import running_gateway, scan_rows
from tests.support.mosquitto import Mosquitto, mqtt_probe, unique_base_topic
from tests.support.mqtt_setup import FAST_POLL, mqtt_config
from tests.support.processes import run_cli, simulator_process
from tests.support.protocol_frames import PROTOCOL_EXCHANGES
from tests.support.serial_master import exchange

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
    gd350a = get_profile("gd350a").telemetry(registers)
    gd30 = get_profile("gd30").telemetry(registers)
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
    assert isinstance(profile, InvtProfile)
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


# ---------------------------------------------------------------- the simulated series


@pytest.mark.parametrize("series", FIVE_SERIES)
def test_every_protocol_frame_against_each_simulated_series(series: str) -> None:
    with (
        SimulatedLine(
            addresses=[1, 2, 3], model=series, baudrate=19200, fault_history={3: [35] * 6}
        ) as line,
        serial.Serial(line.path, 19200, parity="E", timeout=1) as port,
    ):
        for request_hex, reply_hex in PROTOCOL_EXCHANGES:
            reply = exchange(port, bytes.fromhex(request_hex))
            assert reply == bytes.fromhex(reply_hex), (
                f"{series}: {request_hex} answered {reply.hex(' ').upper()}"
            )
            time.sleep(0.003)  # t3.5 before the next request, as a master must
        assert line.stats["gap_violations"] == 0


def test_each_simulated_series_answers_its_own_identification() -> None:
    answers = {}
    with (
        SimulatedLine(
            addresses=[1, 2, 3, 4, 5],
            models=dict(enumerate(FIVE_SERIES, start=1)),
            baudrate=19200,
        ) as line,
        serial.Serial(line.path, 19200, parity="E", timeout=1) as port,
    ):
        for address in range(1, 6):
            request = bytes.fromhex(f"{address:02X} 03 21 03 00 01")
            reply = exchange(port, request + crc(request))
            answers[address] = int.from_bytes(reply[3:5], "big")
            time.sleep(0.003)  # t3.5 before the next request, as a master must
    assert answers == {1: 0x01F0, 2: 0x01F1, 3: 0x01A2, 4: 0x010A, 5: 0x01A1}


def crc(frame: bytes) -> bytes:
    from pymodbus.framer import FramerRTU

    return FramerRTU.compute_CRC(frame).to_bytes(2, "big")


def test_a_goodrive30_takes_the_motors_its_2009h_row_lists() -> None:
    # The Goodrive30 manual (page -135-): 2009H bits 1-0 "=10: Motor 3 =11: Motor 4", while its
    # 2101H marks 10 and 11 "Reserved". The simulator follows the 2009H row: motor 3 is taken.
    assert INVT_PROFILES["gd30"].motors == 2
    with (
        SimulatedLine(addresses=[1], models={1: "gd30"}, baudrate=19200) as line,
        serial.Serial(line.path, 19200, parity="E", timeout=1) as port,
    ):
        select_motor_3 = bytes.fromhex("01 06 20 09 00 02")
        request = select_motor_3 + crc(select_motor_3)
        assert exchange(port, request) == request
        time.sleep(0.003)  # t3.5 before the next request, as a master must
        read_back = bytes.fromhex("01 03 20 09 00 01")
        assert exchange(port, read_back + crc(read_back))[3:5] == b"\x00\x02"


def read_word(port: serial.Serial, address: int, register: int) -> bytes:
    request = bytes.fromhex(f"{address:02X} 03 {register >> 8:02X} {register & 0xFF:02X} 00 01")
    reply = exchange(port, request + crc(request))
    time.sleep(0.003)  # t3.5 before the next request
    return reply


def test_a_gd300l_answers_its_fault_at_5000h_and_its_code_at_3016h() -> None:
    # The Goodrive300-LIFT manual (10.4.5, page -127-): 3016H "Identifying code of the inverter"
    # and 5000H "Fault code", after 2102H and 2103H.
    assert INVT_PROFILES["gd300l"].fault_registers == (0x2102, 0x5000)
    with (
        SimulatedLine(addresses=[4], models={4: "gd300l"}, baudrate=19200) as line,
        serial.Serial(line.path, 19200, parity="E", timeout=1) as port,
    ):
        line.inject_fault(4, 23)
        assert read_word(port, 4, 0x2102)[3:5] == b"\x00\x17"
        assert read_word(port, 4, 0x5000)[3:5] == b"\x00\x17"  # 23 = bCE at both
        assert read_word(port, 4, 0x3016)[3:5] == b"\x01\x0a"  # as 2103H: "GD300 0x010a"
    telemetry = get_profile("gd300l").telemetry({0x2100: 4, 0x2101: 0, 0x5000: 23})
    assert telemetry["fault_description"] == "bCE: braking unit fault"


def test_a_gd300l_reports_ready_with_bit_0_clear() -> None:
    # The Goodrive300-LIFT manual: 2101H bit 0 "=0: ready for operation".
    registers = {0x2100: 3, 0x2101: 0x0040, 0x2102: 0}
    assert get_profile("gd300l").telemetry(registers)["ready"] is True
    assert get_profile("gd20").telemetry(registers)["ready"] is False


# ---------------------------------------------------------------- scan


def test_scan_names_each_series_as_far_as_its_code_tells() -> None:
    drives = [arg for i, m in enumerate(FIVE_SERIES, start=1) for arg in ("--drive", f"{i}={m}")]
    line = ("--baud", "115200", "--parity", "N")
    with simulator_process(
        *drives, *line, "--response-delay-ms", "2", "--fault", "1=40", "--fault", "3=40"
    ) as sim:
        result = run_cli("scan", "--port", sim.path, *line, "--addresses", "1-6")
    assert result.returncode == 0, result.stderr
    rows = scan_rows(result.stdout)
    assert {address: cells[0] for address, cells in rows.items()} == {
        1: "GD30 (01F0H unconfirmed)",
        2: "IPE300 (01F1H unconfirmed)",
        3: "GD350A",
        4: "GD300 or GD300-LIFT",
        5: "GD350-UL",
    }
    assert rows[1][2] == "unknown fault 40"  # a Goodrive30 lists no fault 40
    assert rows[3][2] == "STO"  # a Goodrive350A does
    assert rows[2][1:3] == ["stopped", "none"]


def test_scan_shows_an_unplaceable_invt_code_raw() -> None:
    drive = FoundDrive(9, identification=0x0150, state_word_1=3, state_word_2=0x40, fault=35)
    assert drive.model == "unknown series (0150H)"
    assert drive.fault_text == "STo: maladjustment"


# ---------------------------------------------------------------- MQTT


async def test_a_fault_one_series_lists_is_unknown_for_another_over_mqtt(
    mosquitto: Mosquitto,
) -> None:
    base = unique_base_topic()
    drives = [
        {"name": "hoist1", "address": 1, "model": "gd350a", "poll": FAST_POLL},
        {"name": "fan2", "address": 2, "model": "gd30", "poll": FAST_POLL},
    ]
    with SimulatedLine(
        addresses=[1, 2], models={1: "gd350a", 2: "gd30"}, baudrate=115200, response_delay_ms=1
    ) as line:
        config = mqtt_config(line.path, mosquitto, base, drives=drives, bus={"baudrate": 115200})
        async with mqtt_probe(mosquitto, f"{base}/#") as probe, running_gateway(config):
            await probe.wait_for(f"{base}/hoist1")
            await probe.wait_for(f"{base}/fan2")
            line.inject_fault(1, 40)
            line.inject_fault(2, 40)
            hoist = await probe.wait_for(f"{base}/hoist1", lambda s: s["fault_code"] == 40)
            fan = await probe.wait_for(f"{base}/fan2", lambda s: s["fault_code"] == 40)
            assert (hoist.json()["fault_name"], hoist.json()["fault_description"]) == (
                "STO",
                "STO",
            )
            assert (fan.json()["fault_name"], fan.json()["fault_description"]) == (
                "40",
                "unknown fault 40",
            )
            # Both drives' events, in whichever order their polls found the faults.
            for name in ("hoist1", "fan2"):
                await probe.wait_for(
                    f"{base}/bridge/event",
                    lambda e, name=name: e["type"] == "fault_raised" and e["data"]["drive"] == name,
                )
            events = {
                e.json()["data"]["drive"]: e.json()["data"]
                for e in probe.on(f"{base}/bridge/event")
                if e.json()["type"] == "fault_raised"
            }
            assert events["fan2"]["fault_description"] == "unknown fault 40"
            assert events["hoist1"]["fault_name"] == "STO"


# ---------------------------------------------------------------- Home Assistant


async def test_discovery_set_point_maximum_is_the_drives_own_p00_03(mosquitto: Mosquitto) -> None:
    base = unique_base_topic()
    prefix = unique_base_topic("ha")
    drives = [
        {"name": "hoist1", "address": 1, "model": "gd350a", "poll": FAST_POLL},
        {"name": "lift2", "address": 2, "model": "gd300l", "poll": FAST_POLL},
    ]
    with SimulatedLine(
        addresses=[1, 2], models={1: "gd350a", 2: "gd300l"}, baudrate=115200, response_delay_ms=1
    ) as line:
        with serial.Serial(line.path, 115200, parity="E", timeout=1) as port:
            set_max = bytes.fromhex("01 06 00 03 17 70")  # P00.03 = 60.00 Hz
            assert exchange(port, set_max + crc(set_max)) == set_max + crc(set_max)
        line.set_dead(2, True)  # lift2 can't be asked: its profile's factory 50.00 Hz
        config = mqtt_config(
            line.path, mosquitto, base, drives=drives, bus={"baudrate": 115200},
            discovery_prefix=prefix,
        )  # fmt: skip
        async with mqtt_probe(mosquitto, f"{prefix}/#") as probe, running_gateway(config):
            hoist = await probe.wait_for(
                f"{prefix}/number/invt_test/hoist1_frequency_setpoint/config"
            )
            lift = await probe.wait_for(
                f"{prefix}/number/invt_test/lift2_frequency_setpoint/config"
            )
            assert hoist.json()["max"] == 60.0
            assert lift.json()["max"] == 50.0
            assert lift.json()["device"]["model"] == "GD300-LIFT"
