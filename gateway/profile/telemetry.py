"""A drive's polled registers as telemetry: state, fault and running values in engineering units.

What the poller reads (2100H-2102H, 3000H-300BH) becomes one flat mapping whose keys carry their
unit (`output_frequency_hz`, `bus_voltage_v`), so a dashboard needs no INVT manual:

    {"state": "running_forward", "state_word_1": 1, "state_word_2": 65, "ready": true,
     "command_source": "communication", "fault_code": 0, "fault_name": "none",
     "fault_description": "none", "output_frequency_hz": 35.0, "bus_voltage_v": 540.2, ...}

Keys whose registers have not been read yet are absent rather than guessed.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Final

from gateway.profile.faults import GD350_FAULTS, NO_FAULT, FaultTable
from gateway.profile.invt import STATE_WORD_1, DriveProfile
from gateway.profile.registers import RUNNING_VALUES
from gateway.profile.states import decode_state_word_1, decode_state_word_2

STATE_WORD_2: Final = STATE_WORD_1 + 1

TelemetryValue = str | int | float | bool
Telemetry = dict[str, TelemetryValue]


def fault_name(code: int, table: FaultTable = GD350_FAULTS) -> str:
    """The keypad's short code ("OL1"), "none" for 0, the number for a code `table` doesn't
    list."""
    return "none" if code == NO_FAULT else table.short_code(code)


def fault_fields(code: int, table: FaultTable = GD350_FAULTS) -> Telemetry:
    """The fault as the drive's own series names it: a code outside its table is
    "unknown fault N", never another series' name for that number."""
    return {
        "fault_code": code,
        "fault_name": fault_name(code, table),
        "fault_description": table.describe(code),
    }


def decode_telemetry(profile: DriveProfile, registers: Mapping[int, int]) -> Telemetry:
    """Telemetry from the latest raw value of each polled register (address → word)."""
    telemetry: Telemetry = {}
    state_word_1 = registers.get(STATE_WORD_1)
    if state_word_1 is not None:
        telemetry["state"] = decode_state_word_1(state_word_1)
        telemetry["state_word_1"] = state_word_1
    state_word_2 = registers.get(STATE_WORD_2)
    if state_word_2 is not None:
        decoded = decode_state_word_2(state_word_2, profile.ready_bit_set_means_ready)
        telemetry["state_word_2"] = state_word_2
        telemetry["ready"] = decoded.ready
        telemetry["command_source"] = decoded.command_source
        telemetry["overload_pre_alarm"] = decoded.overload_pre_alarm
    fault = current_fault(profile, registers)
    if fault is not None:
        telemetry.update(fault_fields(fault, profile.faults))
    for running in RUNNING_VALUES:
        raw = registers.get(running.register.address)
        if raw is not None:
            register = running.register
            telemetry[running.key] = register.decode(
                raw, profile.decimals(register.name, register.decimals)
            )
    return telemetry


def current_fault(profile: DriveProfile, registers: Mapping[int, int]) -> int | None:
    """The fault code from the first of the profile's fault registers that was read."""
    for register in profile.fault_registers:
        if register in registers:
            return registers[register]
    return None
