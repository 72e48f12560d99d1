"""ABB drives (ACS355, ACS580) on the ABB Drives profile: a second maker behind the same
`DriveProfile` protocol. The control words and bits asserted here are read off the manual pages
`gateway/profile/data/abb_drives.yaml` cites, not off the module."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest
import yaml

from gateway.config import GatewayConfig
from gateway.console.decode import describe
from gateway.instruments.simulator import SimulatedLine
from gateway.modbus.functions import READ_HOLDING_REGISTERS
from gateway.profile import get_profile
from gateway.profile.states import RunState
from tests.support import eventually, running_gateway, scan_rows
from tests.support.console_support import OPERATOR_PASSWORD, console_client, console_config
from tests.support.mosquitto import Mosquitto, mqtt_probe, unique_base_topic
from tests.support.mqtt_setup import FAST_POLL, mqtt_config
from tests.support.processes import run_cli

# ACS355 state diagram, page 319: CW = xxxx x1xx xxxx x110 → READY TO SWITCH ON,
# xxxx x1xx xxxx x111 → READY TO OPERATE, xxxx x1xx x111 1111 → OPERATING.
READY_TO_SWITCH_ON = 0b0000_0100_0111_0110
READY_TO_OPERATE = 0b0000_0100_0111_0111
OPERATING = 0b0000_0100_0111_1111
CONTROL_WORD = 40001 - 40001  # the manuals' 40001 is address 0 on the wire
INVT_STATES = {state.name.lower() for state in RunState}


@pytest.mark.parametrize("model", ["acs355", "ACS580"])
def test_run_forward_walks_the_state_machine_as_the_manual_gives_it(model: str) -> None:
    profile = get_profile(model)
    reference = profile.setpoint_word(25.0)
    assert reference == 10000  # ±20000 is the full scale: 25 Hz of 50 Hz
    writes = profile.control_writes(profile.command_name("run_forward"), reference)
    assert [(w.start, w.words) for w in writes] == [
        (CONTROL_WORD, (READY_TO_SWITCH_ON, reference)),  # 40001-40002 in one write
        (CONTROL_WORD, (READY_TO_OPERATE,)),
        (CONTROL_WORD, (OPERATING,)),
    ]
    assert writes[0].pause_s >= 0.1  # "Wait at least 100 ms before proceeding"


def test_reverse_is_a_negative_reference_and_needs_one() -> None:
    profile = get_profile("acs580")
    writes = profile.control_writes("run_reverse", profile.setpoint_word(25.0))
    assert writes[0].words == (READY_TO_SWITCH_ON, (-10000) & 0xFFFF)
    with pytest.raises(ValueError, match="negative reference"):
        profile.control_writes("run_reverse", None)


def test_stop_and_fault_reset_are_the_manuals_bits() -> None:
    profile = get_profile("acs580")
    (stop,) = profile.control_writes("stop", None)
    assert stop.words[0] & 0b1 == 0  # OFF1 = 0: stop along the active ramp
    (coast,) = profile.control_writes("coast_stop", None)
    assert coast.words[0] & 0b10 == 0  # OFF2 = 0: coast to a stop
    low, high = profile.control_writes("fault_reset", None)
    assert (low.words[0] & 0x80, high.words[0] & 0x80) == (0, 0x80)  # bit 7: a rising edge


@pytest.mark.parametrize(
    ("status_word", "reference", "state"),
    [
        (0b0000_0010_0011_0111, 10000, "running_forward"),  # RDY_REF: operation enabled
        (0b0000_0010_0011_0111, (-10000) & 0xFFFF, "running_reverse"),
        (0b0000_0010_0011_0011, 0, "stopped"),  # ready to operate, not enabled
        (0b0000_0010_0011_1000, 0, "fault"),  # TRIPPED
        (0b0000_0000_0100_0000, 0, "stopped"),  # switch-on inhibited
    ],
)
def test_the_status_word_reads_in_the_words_invt_drives_use(
    status_word: int, reference: int, state: str
) -> None:
    telemetry = get_profile("acs580").telemetry({0: 0, 1: reference, 3: status_word})
    assert telemetry["state"] == state
    assert telemetry["state"] in INVT_STATES  # what MQTT and the console show for any drive
    assert telemetry["ready"] is bool(status_word & 0b10)  # RDY_RUN: ready to operate
    assert telemetry["command_source"] == ("remote" if status_word & 0x200 else "local")


def test_its_registers_are_named_by_the_manuals_numbers() -> None:
    profile = get_profile("acs355")
    point = profile.resolve("40004")
    assert (point.address, point.description) == (3, "status word")
    assert point.show(0x0237, profile).startswith(
        "0237H (running, direction by reference 1: ready to switch on"
    )
    assert profile.resolve("reference_1").show((-10000) & 0xFFFF, profile) == "-10000"
    assert profile.point(0x2100) is None  # INVT's state word is no ABB register


# ---------------------------------------------------------------- a mixed line, end to end


def test_the_traffic_monitor_reads_an_abb_status_word_in_the_manuals_words() -> None:
    profile = get_profile("acs580")
    request = struct.pack(">BHH", READ_HOLDING_REGISTERS, 3, 1)
    line = describe(request, bytes((READ_HOLDING_REGISTERS, 2, 0x02, 0x37)), profile)
    assert line == (
        "read 40004 status word → 0237H (running, direction by reference 1: ready to switch on, "
        "ready to operate, "
        "operation enabled, OFF2 inactive, OFF3 inactive, remote)"
    )


def test_scan_shows_an_abb_drive_beside_an_invt_one() -> None:
    with SimulatedLine(addresses=[1, 2], models={2: "acs580"}, baudrate=115200) as line:
        result = run_cli(
            "scan", "--port", line.path, "--baud", "115200", "--addresses", "1-3",
            env={"COLUMNS": "200"},  # the table's note column, untruncated
        )  # fmt: skip
    assert result.returncode == 0, result.stderr
    rows = scan_rows(result.stdout)
    assert sorted(rows) == [1, 2]
    assert rows[1][:2] == ["GD350", "stopped"]
    assert rows[2][:4] == ["ACS355 or ACS580 (ABB Drives profile)", "stopped", "none", "remote"]


async def test_run_forward_over_mqtt_starts_an_abb_drive_as_it_does_an_invt_one(
    mosquitto: Mosquitto,
) -> None:
    base = unique_base_topic()
    drives = [
        {"name": "pump1", "address": 1, "model": "gd350", "poll": FAST_POLL},
        {"name": "fan2", "address": 2, "model": "acs580"},  # its profile's poll: 40001-40012
    ]
    with SimulatedLine(
        addresses=[1, 2], models={2: "acs580"}, baudrate=115200, response_delay_ms=1
    ) as line:
        config = mqtt_config(
            line.path, mosquitto, base, drives=drives, bus={"baudrate": 115200},
            discovery_prefix=f"{base}/ha",
        )  # fmt: skip
        async with mqtt_probe(mosquitto, f"{base}/#") as probe, running_gateway(config):
            for name in ("pump1", "fan2"):
                await probe.wait_for(f"{base}/{name}", lambda s: s.get("state") == "stopped")
                answer = await probe.request(
                    f"{base}/{name}/set",
                    {"command": "run_forward", "frequency_hz": 25.0},
                    f"{base}/{name}/set/response",
                )
                assert answer["status"] == "ok", answer
                await probe.wait_for(
                    f"{base}/{name}", lambda s: s.get("state") == "running_forward"
                )
            drive = line.abb_drives[2]
            assert drive.words[1] == 10000  # 25 Hz of the 50 Hz full scale (20000)
            answer = await probe.request(
                f"{base}/fan2/set",
                {"command": "run_reverse", "frequency_hz": 10.0},
                f"{base}/fan2/set/response",
            )
            assert answer["status"] == "ok", answer
            await probe.wait_for(f"{base}/fan2", lambda s: s.get("state") == "running_reverse")
            await probe.request(
                f"{base}/fan2/set", {"command": "stop"}, f"{base}/fan2/set/response"
            )
            await probe.wait_for(f"{base}/fan2", lambda s: s.get("state") == "stopped")
            state = await probe.wait_for(f"{base}/ha/sensor/invt_test/fan2_state/config")
            assert state.json()["device"]["manufacturer"] == "ABB"
            assert probe.on(f"{base}/ha/button/invt_test/fan2_run_forward/config")
            assert not probe.on(f"{base}/ha/sensor/invt_test/fan2_output_frequency_hz/config")


async def test_the_console_starts_an_abb_drive_and_shows_it_running() -> None:
    with SimulatedLine(
        addresses=[1, 2], models={2: "acs580"}, baudrate=115200, response_delay_ms=1
    ) as line:
        settings = console_config(line.path).model_dump()
        settings["drives"][1]["model"] = "acs580"  # fan2
        config = GatewayConfig.model_validate(settings)
        async with running_gateway(config) as app, console_client(app) as web:
            await web.login("olga", OPERATOR_PASSWORD)
            status, body = await web.post("/api/drives/fan2/frequency", {"hz": 25.0})
            assert (status, body["write"]) == (200, "40002 reference 1 = 10000")
            status, body = await web.post("/api/drives/fan2/command", {"command": "run_forward"})
            assert status == 200, body
            assert body["write"].split("; ") == [
                "40001 control word = 1142",  # 0476H, 0477H, 047FH
                "40001 control word = 1143",
                "40001 control word = 1151",
            ]

            async def running() -> bool:
                drives = (await web.get_json("/api/overview"))["drives"]
                fan = next(d for d in drives if d["name"] == "fan2")
                return bool(fan["state"] == "running forward")  # as it shows an INVT drive's

            await eventually(running)
            assert line.abb_drives[2].state(0.0) is RunState.RUNNING_FORWARD


def test_a_site_names_an_abb_fault_and_is_told_what_doesnt_apply(tmp_path: Path) -> None:
    """`drives[].faults` corrects an ABB drive's fault names as it does an INVT drive's (the
    rest of the profile kept); the INVT-only corrections are refused by `check-config`."""
    profile = get_profile("acs580").with_overrides(faults={0x2310: "OC: overcurrent"})
    assert profile.faults.describe(0x2310) == "OC: overcurrent"
    assert (profile.display_name, profile.commands) == ("ACS580", get_profile("acs580").commands)
    config = {
        "modbus_tcp": {"host": "127.0.0.1", "port": 5020},
        "buses": [{"name": "line1", "port": "/dev/null"}],
        "drives": [
            {"name": "fan7", "bus": "line1", "address": 1, "model": "acs580", "faults": {1: "x"}},
            {
                "name": "fan8", "bus": "line1", "address": 2, "model": "acs355",
                "identification": ["01A0H"],
            },
        ],
    }  # fmt: skip
    path = tmp_path / "abb.yaml"
    path.write_text(yaml.safe_dump(config))
    result = run_cli("check-config", "--config", str(path))
    assert result.returncode == 3
    assert "drives[1] (fan8): identification: ACS355 has no 2103H code to correct" in result.stderr
    assert "fan7" not in result.stderr
