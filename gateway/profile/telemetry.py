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
from typing import Final, Protocol

from gateway.profile import words
from gateway.profile.invt_codes import STATE_WORD_1
from gateway.profile.registers import RUNNING_VALUES

STATE_WORD_2: Final = STATE_WORD_1 + 1

TelemetryValue = str | int | float | bool
Telemetry = dict[str, TelemetryValue]

TELEMETRY_KEYS: Final = frozenset(
    {
        "state",
        "state_word_1",
        "state_word_2",
        "ready",
        "command_source",
        "overload_pre_alarm",
        "fault_code",
        "fault_name",
        "fault_description",
        *(running.key for running in RUNNING_VALUES),
    }
)
"""Every key `decode_telemetry` can write."""


class Series(words.Series, Protocol):
    """What the telemetry reads of an INVT series (`invt.InvtProfile`), besides its words."""

    @property
    def fault_registers(self) -> tuple[int, ...]: ...

    def decimals(self, register_name: str, default: int) -> int: ...


def fault_fields(profile: Series, code: int) -> Telemetry:
    """The fault word's decoder (`words.fault`) as telemetry: a code outside the series' table
    is "unknown fault N", never another series' name for that number. `fault_description` is
    the line to show ("OH2: inverter module overheat"): it holds `fault_name` already."""
    decoded = words.fault(profile, code)
    return {
        "fault_code": decoded.code,
        "fault_name": decoded.name,
        "fault_description": decoded.description,
    }


def decode_telemetry(profile: Series, registers: Mapping[int, int]) -> Telemetry:
    """Telemetry from the latest raw value of each polled register (address → word)."""
    telemetry: Telemetry = {}
    state_word_1 = registers.get(STATE_WORD_1)
    if state_word_1 is not None:
        telemetry["state"] = words.state_word_1(state_word_1)
        telemetry["state_word_1"] = state_word_1
    state_word_2 = registers.get(STATE_WORD_2)
    if state_word_2 is not None:
        decoded = words.state_word_2(profile, state_word_2)
        telemetry["state_word_2"] = state_word_2
        if decoded.ready is not None:  # always, with a profile
            telemetry["ready"] = decoded.ready
        telemetry["command_source"] = decoded.command_source
        telemetry["overload_pre_alarm"] = decoded.overload_pre_alarm
    fault = current_fault(profile, registers)
    if fault is not None:
        telemetry.update(fault_fields(profile, fault))
    for running in RUNNING_VALUES:
        raw = registers.get(running.register.address)
        if raw is not None:
            register = running.register
            telemetry[running.key] = register.decode(
                raw, profile.decimals(register.name, register.decimals)
            )
    return telemetry


def current_fault(profile: Series, registers: Mapping[int, int]) -> int | None:
    """The fault code from the first of the profile's fault registers that was read."""
    for register in profile.fault_registers:
        if register in registers:
            return registers[register]
    return None
