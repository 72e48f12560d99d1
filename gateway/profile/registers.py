"""The communication registers of INVT drives (2000H-200EH, 2100H-2103H, 3000H-3016H, 5000H).

A value with n decimals in the manual travels as value x 10^n (50.12 Hz → 1394H). Signed values are
16-bit two's complement (output torque -10.0 % → FF9CH).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Final


@dataclass(frozen=True)
class Register:
    name: str
    address: int
    decimals: int = 0
    unit: str = ""
    signed: bool = False
    readable: bool = True
    writable: bool = False
    description: str = ""
    minimum: int | None = None
    """Lowest value a write may carry (signed registers: as a signed number); None: any."""
    maximum: int | None = None
    maximum_from: str | None = None
    """A parameter whose value is the upper bound instead (2001H: 0 ... P00.03)."""

    def decode(self, raw: int, decimals: int | None = None) -> float | int:
        """Engineering value of a raw 16-bit word (an int when the register has no decimals)."""
        value = to_signed(raw) if self.signed else raw & 0xFFFF
        places = self.decimals if decimals is None else decimals
        return value / float(10**places) if places else value

    def encode(self, value: float, decimals: int | None = None) -> int:
        """Raw 16-bit word of an engineering value; ValueError when it doesn't fit."""
        places = self.decimals if decimals is None else decimals
        scaled = value * float(10**places)
        if not math.isfinite(scaled):  # round() would raise OverflowError (or ValueError)
            raise ValueError(f"{self.name} = {value} does not fit in one register")
        raw = round(scaled)
        low, high = (-0x8000, 0x7FFF) if self.signed else (0, 0xFFFF)
        if not low <= raw <= high:
            raise ValueError(f"{self.name} = {value} does not fit in one register ({raw})")
        return raw & 0xFFFF


def to_signed(raw: int) -> int:
    raw &= 0xFFFF
    return raw - 0x10000 if raw & 0x8000 else raw


_R = Register
COMMUNICATION_REGISTERS: Final[tuple[Register, ...]] = (
    _R(
        "control_word",
        0x2000,
        readable=False,
        writable=True,
        minimum=1,
        maximum=8,
        description="1 forward run ... 8 jog stop (write-only)",
    ),
    _R("frequency_setpoint", 0x2001, 2, "Hz", writable=True, minimum=0, maximum_from="P00.03"),
    _R("pid_reference_setpoint", 0x2002, 1, "%", writable=True, minimum=0, maximum=1000),
    _R("pid_feedback_setpoint", 0x2003, 1, "%", writable=True, minimum=0, maximum=1000),
    _R("torque_setpoint", 0x2004, 1, "%", signed=True, writable=True, minimum=-3000, maximum=3000),
    _R("forward_frequency_limit", 0x2005, 2, "Hz", writable=True, minimum=0, maximum_from="P00.03"),
    _R("reverse_frequency_limit", 0x2006, 2, "Hz", writable=True, minimum=0, maximum_from="P00.03"),
    _R("motoring_torque_limit", 0x2007, 1, "%", writable=True, minimum=0, maximum=3000),
    _R("braking_torque_limit", 0x2008, 1, "%", writable=True, minimum=0, maximum=3000),
    _R(
        "special_control_word",
        0x2009,
        writable=True,
        description="bits 1-0 motor, bit 2 torque control, bit 4 pre-excitation, bit 5 DC brake",
    ),
    _R("virtual_input_terminals", 0x200A, writable=True),
    _R("virtual_output_terminals", 0x200B, writable=True),
    _R("vf_separation_voltage", 0x200C, 1, "%", writable=True, minimum=0, maximum=1000),
    _R("ao1_output", 0x200D, 1, "%", signed=True, writable=True, minimum=-1000, maximum=1000),
    _R("ao2_output", 0x200E, 1, "%", signed=True, writable=True, minimum=-1000, maximum=1000),
    _R("state_word_1", 0x2100, description="1 fwd, 2 rev, 3 stopped, 4 fault, 5 POFF, 6 pre-exc."),
    _R("state_word_2", 0x2101, description="bit 0 ready, bits 6-5 command source"),
    _R("fault_code", 0x2102),
    _R("identification", 0x2103),
    _R("running_frequency", 0x3000, 2, "Hz"),
    _R("set_frequency", 0x3001, 2, "Hz"),
    _R("bus_voltage", 0x3002, 1, "V"),
    _R("output_voltage", 0x3003, 0, "V"),
    _R("output_current", 0x3004, 1, "A"),
    _R("rotation_speed", 0x3005, 0, "rpm"),
    _R("output_power", 0x3006, 1, "%", signed=True),
    _R("output_torque", 0x3007, 1, "%", signed=True),
    _R("pid_reference", 0x3008, 1, "%", signed=True),
    _R("pid_feedback", 0x3009, 1, "%", signed=True),
    _R("input_terminals", 0x300A, description="bit map"),
    _R("output_terminals", 0x300B, description="bit map"),
    _R("ai1_voltage", 0x300C, 2, "V"),
    _R("ai2_voltage", 0x300D, 2, "V"),
    _R("ai3_voltage", 0x300E, 2, "V"),
    _R("ai4_voltage", 0x300F, 2, "V"),
    _R("hdia_frequency", 0x3010, 2, "kHz"),
    _R("hdib_frequency", 0x3011, 2, "kHz"),
    _R("multi_step_speed_step", 0x3012, description="0-15"),
    _R("length", 0x3013),
    _R("count", 0x3014),
    _R("torque_reference", 0x3015, 1, "%", signed=True),
    _R("identification_mirror", 0x3016, description="same as 2103H"),
    _R("fault_code_5000", 0x5000, description="GD350 family and GD300-LIFT"),
)
del _R

_BY_NAME: Final = {register.name: register for register in COMMUNICATION_REGISTERS}
_BY_ADDRESS: Final = {register.address: register for register in COMMUNICATION_REGISTERS}


def register_by_name(name: str) -> Register:
    try:
        return _BY_NAME[name]
    except KeyError:
        raise ValueError(f"unknown register {name!r}: known are {', '.join(_BY_NAME)}") from None


def register_at(address: int) -> Register | None:
    """The communication register at `address`, or None (a parameter, or nothing)."""
    return _BY_ADDRESS.get(address)


@dataclass(frozen=True)
class RunningValue:
    """A telemetry key (what the MQTT bridge publishes) and the register it comes from."""

    key: str
    register: Register


RUNNING_VALUES: Final[tuple[RunningValue, ...]] = tuple(
    RunningValue(key, register_by_name(name))
    for key, name in (
        ("output_frequency_hz", "running_frequency"),
        ("set_frequency_hz", "set_frequency"),
        ("bus_voltage_v", "bus_voltage"),
        ("output_voltage_v", "output_voltage"),
        ("output_current_a", "output_current"),
        ("rotation_speed_rpm", "rotation_speed"),
        ("output_power_pct", "output_power"),
        ("output_torque_pct", "output_torque"),
        ("pid_reference_pct", "pid_reference"),
        ("pid_feedback_pct", "pid_feedback"),
        ("input_terminals", "input_terminals"),
        ("output_terminals", "output_terminals"),
    )
)
RUNNING_VALUES_BY_ADDRESS: Final = {value.register.address: value for value in RUNNING_VALUES}


def decode_running_values(
    start: int,
    words: Sequence[int],
    decimals_overrides: Mapping[str, int] | None = None,
) -> dict[str, float | int]:
    """Telemetry from a block read at `start`: {"output_frequency_hz": 50.0, ...}.

    Words at addresses that are not running values are skipped. `decimals_overrides` maps a
    register name to the decimals a model uses instead (see `InvtProfile.decimals_overrides`).
    """
    overrides = decimals_overrides or {}
    values: dict[str, float | int] = {}
    for offset, raw in enumerate(words):
        running = RUNNING_VALUES_BY_ADDRESS.get(start + offset)
        if running is not None:
            register = running.register
            values[running.key] = register.decode(raw, overrides.get(register.name))
    return values
