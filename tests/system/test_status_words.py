"""One answer per status word, whichever surface asks: every series, every defined bit and value.

A drive's state word 1 (2100H), state word 2 (2101H) and fault code (2102H) are decoded by the
real functions each surface uses (the telemetry behind MQTT, Home Assistant and the console's
drive page; the line `invt-gateway read` prints; the console's traffic monitor; `scan`; the fault
events), and all must agree. 2101H bit 0 is checked against the manuals' own words, and the
simulator against them too; the last test asks a real gateway with a simulated line through MQTT,
`invt-gateway read --via` and the console's API at once.
"""

from __future__ import annotations

import asyncio
import struct
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import aiohttp
import pytest

from gateway.console.decode import describe
from gateway.console.events import MemoryEventStore
from gateway.console.live import LiveState
from gateway.instruments.simulator import SimulatedLine
from gateway.instruments.simulator.drive import SimulatedDrive
from gateway.mqtt.discovery import SENSORS
from gateway.poller.drive_state import DriveState, EventKind
from gateway.profile import InvtProfile, get_profile, resolve
from gateway.profile.abb import SCAN_QUESTION
from gateway.profile.invt import INVT_PROFILES, UNCONFIRMED_READY_BIT
from gateway.profile.states import RunState
from gateway.profile.telemetry import decode_telemetry
from gateway.tools.access import Reading
from gateway.tools.scan import FoundDrive
from tests.support import free_port, read_pdu
from tests.support.mosquitto import mqtt_probe, running_mosquitto, unique_base_topic
from tests.support.processes import gateway_process, run_cli

INVT = list(INVT_PROFILES.values())

# 2101H bit 0: the value that means "ready", in each series' own communication chapter (the
# pages are quoted in the profiles' `ready_bit_source`; these are read off the pages again).
MANUAL_READY_VALUE = {
    "gd300": 1,  # Goodrive300, page 219: "=0: not ready for operation =1: ready for operation"
    "gd350": 1,  # Goodrive350 IP55, page -282-: "=0: Not ready to run =1: Ready to run"
    "gd30": 1,  # Goodrive30, page -135-: "=0: Not ready to run =1: Ready to run"
    "gd10": 1,  # Goodrive10, page 87: "=1: bus voltage is established"
    "gd35": 0,  # Goodrive35, page 279: "=0: ready for operation =1: not ready for operation"
    "gd300l": 0,  # Goodrive300-LIFT, page -126-: "=0: ready for operation =1: not ready"
}


def ready_in(text: str) -> bool | None:
    """What a printed state word 2 says about bit 0: ready, not ready, or undecided."""
    if "(not ready," in text:
        return False
    if "(ready," in text:
        return True
    assert "depends on the series" in text, text
    return None


def monitor_line(profile: InvtProfile, address: int, raw: int) -> str:
    """The traffic monitor's meaning of a one-word read of `address` that answered `raw`."""
    return describe(read_pdu(address), struct.pack(">BBH", 3, 2, raw), profile)


def scanned(
    profile: InvtProfile,
    state_word_1: int | None = None,
    state_word_2: int | None = None,
    fault: int | None = None,
) -> FoundDrive:
    """What `scan` found at a drive of this series that answered these words."""
    code = profile.identification[0]
    return FoundDrive(1, code, state_word_1, state_word_2, fault)


# ---------------------------------------------------------------- the manuals, the profiles


@pytest.mark.parametrize("profile", INVT, ids=lambda p: p.key)
def test_each_polarity_cites_its_page_or_says_it_is_unconfirmed(profile: InvtProfile) -> None:
    if profile.key in MANUAL_READY_VALUE:
        assert profile.ready_bit_set_means_ready == (MANUAL_READY_VALUE[profile.key] == 1)
        assert "page" in profile.ready_bit_source
        assert UNCONFIRMED_READY_BIT not in profile.unconfirmed
    else:  # no page found: the common reading, said to be a guess
        assert profile.ready_bit_source == ""
        assert UNCONFIRMED_READY_BIT in profile.unconfirmed


@pytest.mark.parametrize("profile", INVT, ids=lambda p: p.key)
def test_the_simulator_answers_2101h_as_the_manual_says(profile: InvtProfile) -> None:
    drive = SimulatedDrive(1, profile.key)
    ready_value = 1 if profile.ready_bit_set_means_ready else 0
    if profile.key in MANUAL_READY_VALUE:
        assert ready_value == MANUAL_READY_VALUE[profile.key]

    def bit_0() -> int:
        reply = drive.handle(read_pdu(0x2101), 0.0)
        return int.from_bytes(reply[2:4], "big") & 1

    assert bit_0() == ready_value  # stopped, no fault: ready to run
    drive.inject_fault(16, 0.0)
    assert bit_0() == 1 - ready_value  # in fault: not ready


# ---------------------------------------------------------------- every surface, one answer


@pytest.mark.parametrize("profile", INVT, ids=lambda p: p.key)
def test_state_word_2_every_bit_reads_the_same_everywhere(profile: InvtProfile) -> None:
    point = resolve("2101H")
    for raw in range(0x80):  # bits 0-6: every bit the manuals define
        telemetry = decode_telemetry(profile, {0x2101: raw})
        read_line = Reading(point, raw, profile).line()
        monitor = monitor_line(profile, 0x2101, raw)
        expected = bool(raw & 1) == profile.ready_bit_set_means_ready
        assert telemetry["ready"] is expected, (profile.key, raw)
        assert ready_in(read_line) is expected, read_line
        assert ready_in(monitor) is expected, monitor
        source = telemetry["command_source"]
        assert f"command source {source}" in read_line
        assert f"command source {source}" in monitor
        assert scanned(profile, state_word_2=raw).command_source == source
        assert telemetry["overload_pre_alarm"] is bool(raw & 0x10)


def test_a_series_the_reader_cannot_tell_leaves_bit_0_undecided() -> None:
    # 010AH is a GD300 or a GD300-LIFT: their bit 0 reads the opposite way.
    assert {p.ready_bit_set_means_ready for p in INVT if 0x010A in p.identification} == {
        True,
        False,
    }
    line = Reading(resolve("2101H"), 0x0041, None).line()
    assert ready_in(line) is None
    assert "command source communication" in line


@pytest.mark.parametrize("profile", INVT, ids=lambda p: p.key)
def test_state_word_1_every_value_reads_the_same_everywhere(profile: InvtProfile) -> None:
    point = resolve("2100H")
    for raw in range(0, 9):  # 1-6 defined, 0, 7 and 8 not
        state = decode_telemetry(profile, {0x2100: raw})["state"]
        assert state == (RunState(raw).name.lower() if 1 <= raw <= 6 else f"unknown_{raw}")
        assert f"{raw} ({state})" in Reading(point, raw, profile).line()
        assert monitor_line(profile, 0x2100, raw).endswith(f"→ {raw:04X}H {state}")
        assert scanned(profile, state_word_1=raw).state == state


@pytest.mark.parametrize("profile", INVT, ids=lambda p: p.key)
def test_every_fault_code_reads_the_same_everywhere(profile: InvtProfile) -> None:
    point = resolve("2102H")
    store = MemoryEventStore()
    live = LiveState({}, [], [], None, store)
    for code in range(1, profile.max_fault_code + 3):  # every code listed, and two beyond
        telemetry = decode_telemetry(profile, {0x2100: 4, 0x2101: 0, 0x2102: code})
        description = str(telemetry["fault_description"])
        name = str(telemetry["fault_name"])
        assert description.startswith(name) or description == f"unknown fault {code}"
        assert f"{code} ({description})" in Reading(point, code, profile).line()
        assert monitor_line(profile, 0x2102, code).endswith(f"→ {code} ({description})")
        if len([p for p in INVT if profile.identification[0] in p.identification]) == 1:
            assert scanned(profile, fault=code).fault_text == description
        # The event a new fault raises, and the console's line for it: the name once.
        state = DriveState("pump1", profile)
        state.record_poll(0x2100, [3, 1, 0], time.time())
        (raised,) = state.record_poll(0x2100, [4, 0, code], time.time())
        assert raised.kind is EventKind.FAULT_RAISED
        assert raised.data["fault_description"] == description
        live.drive_event(raised)
        assert store.recent()[0].text == description
        if name and not name.isdigit():
            assert store.recent()[0].text.count(f"{name}:") <= 1


def test_home_assistant_points_at_keys_the_decoders_fill() -> None:
    registers = {0x2100: 3, 0x2101: 0x41, 0x2102: 16, **{0x3000 + i: 0 for i in range(12)}}
    for profile in INVT:
        telemetry = decode_telemetry(profile, registers)
        assert {sensor.key for sensor in SENSORS} <= telemetry.keys()
        assert telemetry["fault_description"] == "OH2: inverter module overheat"


# ---------------------------------------------------------------- the ABB Drives profile

ABB = [get_profile("acs355"), get_profile("acs580")]
# The status word's bits in the manuals' words: FPBA-01 manual page 113 (bits 0-6), ACS320
# manual page 350 (bits 7-12); 13-15 unused.
ABB_STATUS_BITS = {
    0: "ready to switch on", 1: "ready to operate", 2: "operation enabled", 3: "fault",
    4: "OFF2 inactive", 5: "OFF3 inactive", 6: "switch-on inhibited", 7: "warning",
    8: "at set-point", 9: "remote", 10: "above limit", 11: "EXT2 selected",
    12: "external run enable",
}  # fmt: skip
TRIPPED, OPERATION_ENABLED, READY_TO_OPERATE, REMOTE = 1 << 3, 1 << 2, 1 << 1, 1 << 9
ABB_STATUS_WORD = 40004 - 40001


def abb_expected_state(raw: int, reference: int) -> str:
    """The manuals' reading: TRIPPED (bit 3) is a fault; OPERATION ENABLED (bit 2) runs, in
    reverse on a negative reference (ACS355 manual, page 319); else stopped."""
    if raw & TRIPPED:
        return "fault"
    if raw & OPERATION_ENABLED:
        return "running_reverse" if reference >= 0x8000 else "running_forward"
    return "stopped"


@pytest.mark.parametrize("profile", ABB, ids=lambda p: p.key)
def test_the_abb_status_word_every_bit_reads_the_same_everywhere(profile: Any) -> None:
    """Each bit alone and beside TRIPPED or OPERATION ENABLED, forward and reverse: the state
    MQTT and the console show (the poller's telemetry), `read`, the traffic monitor, `scan`."""
    point = profile.resolve("40004")
    for bit in range(13):
        for raw in {1 << bit, (1 << bit) | TRIPPED, (1 << bit) | OPERATION_ENABLED}:
            for reference in (10000, (-10000) & 0xFFFF):
                state = DriveState("fan1", profile)
                words = [0x047F, reference, 0, raw, *([0] * 8)]
                events = state.record_poll(0, words, time.time())
                telemetry = state.telemetry()  # what MQTT publishes and the console shows
                expected = abb_expected_state(raw, reference)
                assert telemetry["state"] == expected, (bit, raw)
                assert telemetry["ready"] is bool(raw & READY_TO_OPERATE)
                source = "remote" if raw & REMOTE else "local"
                assert telemetry["command_source"] == source
                found = SCAN_QUESTION.answer(tuple(words[:4]))
                assert found is not None
                assert (found.state, found.command_source) == (expected, source)
                assert found.fault == ("tripped" if raw & TRIPPED else "none")
                read_line = Reading(point, raw, profile).line()
                monitor = describe(
                    read_pdu(ABB_STATUS_WORD), struct.pack(">BBH", 3, 2, raw), profile
                )
                # Read alone, the status word can't give a running drive's direction: the
                # line says running and leaves the direction to reference 1, never the other.
                shown = "running, direction by reference 1" if "running" in expected else expected
                for line in (read_line, monitor):
                    assert f"{raw:04X}H ({shown}: " in line, line
                    for each, words_for in ABB_STATUS_BITS.items():
                        assert (words_for in line) is bool(raw & (1 << each)), (line, each)
                # A trip raises no fault event (yet): the fault code is not among the
                # profile's words but a drive parameter whose register differs by family
                # (abb_drives.yaml, `unconfirmed`), so there is no code to name. Said here so
                # that the day it is read, this line fails and the events join the others.
                assert events == []


def test_a_status_word_with_unused_bits_set_is_no_abb_drive_to_scan() -> None:
    # ACS320 manual, page 350: bits 13-15 unused.
    for bit in (13, 14, 15):
        assert SCAN_QUESTION.answer((0, 0, 0, 1 << bit)) is None


# ---------------------------------------------------------------- a real gateway, three surfaces


@pytest.fixture
def line() -> Iterator[SimulatedLine]:
    # Opposite polarities side by side: a GD350 (1 = ready) and a GD300-LIFT (0 = ready); and
    # an ABB drive, whose state comes from its status word.
    with SimulatedLine(
        addresses=[1, 2, 3],
        models={1: "gd350", 2: "gd300l", 3: "acs580"},
        baudrate=115200,
        parity="E",
    ) as simulated:
        yield simulated


def gateway_file(line: SimulatedLine, broker: Any, base: str, tcp: int, web: int) -> dict[str, Any]:
    fast = [{"name": "state", "start": 0x2100, "count": 3, "interval_ms": 150}]
    return {
        "gateway_id": "words",
        "modbus_tcp": {"host": "127.0.0.1", "port": tcp},
        "buses": [{"name": "line1", "port": line.path, "baudrate": 115200, "parity": "E"}],
        "drives": [
            {"bus": "line1", "name": "pump1", "address": 1, "model": "gd350", "poll": fast},
            {"bus": "line1", "name": "lift2", "address": 2, "model": "gd300l", "poll": fast},
            {"bus": "line1", "name": "fan3", "address": 3, "model": "acs580"},
        ],
        "mqtt": {"host": broker.host, "port": broker.port, "base_topic": base},
        "console": {
            "enabled": True,
            "host": "127.0.0.1",
            "port": web,
            "anonymous_view": True,
            "users": [],
        },
    }


async def test_mqtt_read_and_the_console_agree_on_a_real_gateway(
    tmp_path: Path, line: SimulatedLine
) -> None:
    base = unique_base_topic()
    tcp, web = free_port(), free_port()
    via = ("--via", f"tcp://127.0.0.1:{tcp}")
    with (
        running_mosquitto(tmp_path) as broker,
        gateway_process(gateway_file(line, broker, base, tcp, web), tmp_path) as gateway,
    ):
        gateway.wait_ready()
        async with (
            mqtt_probe(broker, f"{base}/+") as probe,
            aiohttp.ClientSession() as session,
        ):
            for faulty in (False, True):
                if faulty:
                    line.inject_fault(1, 16)
                    line.inject_fault(2, 16)
                    line.inject_fault(3, 1)
                for name, unit, model in (("pump1", 1, None), ("lift2", 2, "gd300l")):
                    state = await probe.wait_for(
                        f"{base}/{name}",
                        lambda s, f=faulty: (s.get("fault_code", 0) != 0) == f and "ready" in s,
                    )
                    ready = state.json()["ready"]
                    assert ready is not faulty
                    # The GD300-LIFT answers 010AH, which a GD300 answers too: --model says.
                    model_args = () if model is None else ("--model", model)
                    result = await asyncio.to_thread(
                        run_cli, "read", *via, "-a", str(unit), *model_args, "2101H", "2102H"
                    )
                    assert result.returncode == 0, result.stderr
                    assert ready_in(result.stdout.splitlines()[0]) is ready, result.stdout
                    async with session.get(f"http://127.0.0.1:{web}/api/drives/{name}") as reply:
                        shown = (await reply.json())["telemetry"]
                    assert shown["ready"] is ready
                    assert shown["fault_description"] == state.json()["fault_description"]
                    assert f"({shown['fault_description']})" in result.stdout.splitlines()[1]
                # The ABB drive: MQTT's state, `read 40004` and the console's, tripped or not.
                abb = await probe.wait_for(
                    f"{base}/fan3", lambda s, f=faulty: (s.get("state") == "fault") == f
                )
                said = abb.json()["state"]
                assert said == ("fault" if faulty else "stopped")
                result = await asyncio.to_thread(
                    run_cli, "read", *via, "-a", "3", "--model", "acs580", "40004"
                )
                assert result.returncode == 0, result.stderr
                assert f"({said}: " in result.stdout, result.stdout
                async with session.get(f"http://127.0.0.1:{web}/api/drives/fan3") as reply:
                    assert (await reply.json())["telemetry"]["state"] == said
            async with session.get(f"http://127.0.0.1:{web}/api/events?drive=pump1") as reply:
                texts = [e["text"] for e in (await reply.json())["events"]]
    assert "OH2: inverter module overheat" in texts, texts
    assert not any("OH2: OH2" in text for text in texts)
