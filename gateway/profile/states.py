"""The control word (2000H) and the two state words (2100H, 2101H).

Control word, as the manual lists it: 1 forward run, 2 reverse run, 3 forward jog, 4 reverse jog,
5 stop, 6 coast stop, 7 fault reset, 8 jog stop.
State word 1: 1 forward running, 2 reverse running, 3 stopped, 4 fault, 5 POFF, 6 pre-exciting.
State word 2: bit 0 ready (its polarity differs by series: `InvtProfile.ready_bit_set_means_ready`,
the page it comes from in `ready_bit_source`), bits 2-1 motor, bit 3 synchronous motor, bit 4
overload pre-alarm, bits 6-5 command source (00 keypad, 01 terminal, 10 communication).

These are the bit-level codecs; the surfaces decode a drive's words through
`gateway.profile.words`, which gives each its series' polarity.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum
from typing import Final


class ControlCommand(IntEnum):
    RUN_FORWARD = 1
    RUN_REVERSE = 2
    JOG_FORWARD = 3
    JOG_REVERSE = 4
    STOP = 5
    COAST_STOP = 6
    FAULT_RESET = 7
    JOG_STOP = 8


CONTROL_COMMANDS: Final[dict[str, int]] = {
    command.name.lower(): command for command in ControlCommand
}


def control_command(name: str) -> ControlCommand:
    """The control word value for a command name: `control_command("stop") == 5`."""
    key = name.strip().lower().replace("-", "_").replace(" ", "_")
    if key not in CONTROL_COMMANDS:
        raise ValueError(f"unknown command {name!r}: use one of {', '.join(CONTROL_COMMANDS)}")
    return ControlCommand(CONTROL_COMMANDS[key])


class RunState(IntEnum):
    """State word 1 (2100H)."""

    RUNNING_FORWARD = 1
    RUNNING_REVERSE = 2
    STOPPED = 3
    FAULT = 4
    POWER_OFF = 5
    PRE_EXCITING = 6


def decode_state_word_1(value: int) -> str:
    """ "running_forward", "stopped", "fault", ...; "unknown_<n>" for values INVT doesn't define."""
    try:
        return RunState(value).name.lower()
    except ValueError:
        return f"unknown_{value}"


class CommandSource(IntEnum):
    """State word 2 bits 6-5, also the values of P00.01 (run command channel)."""

    KEYPAD = 0
    TERMINAL = 1
    COMMUNICATION = 2


_READY_BIT: Final = 0x0001
_MOTOR_SHIFT: Final = 1
_SYNCHRONOUS_BIT: Final = 0x0008
_OVERLOAD_PRE_ALARM_BIT: Final = 0x0010
_SOURCE_SHIFT: Final = 5


@dataclass(frozen=True)
class StateWord2:
    ready: bool | None
    """None: the series is not known, and bit 0 reads the opposite way on some series."""
    motor: int
    """1..4: the motor whose parameter set is active."""
    synchronous_motor: bool
    overload_pre_alarm: bool
    command_source: str
    """"keypad", "terminal", "communication", or "unknown_3"."""


def decode_state_word_2(value: int, ready_bit_set_means_ready: bool | None) -> StateWord2:
    """The polarity has no default: a decoder that forgot it would answer for the wrong series
    (`None` when the series is not known: `ready` is None then)."""
    try:
        source = CommandSource((value >> _SOURCE_SHIFT) & 0b11).name.lower()
    except ValueError:
        source = f"unknown_{(value >> _SOURCE_SHIFT) & 0b11}"
    return StateWord2(
        ready=(
            None
            if ready_bit_set_means_ready is None
            else bool(value & _READY_BIT) == ready_bit_set_means_ready
        ),
        motor=((value >> _MOTOR_SHIFT) & 0b11) + 1,
        synchronous_motor=bool(value & _SYNCHRONOUS_BIT),
        overload_pre_alarm=bool(value & _OVERLOAD_PRE_ALARM_BIT),
        command_source=source,
    )


def encode_state_word_2(state: StateWord2, ready_bit_set_means_ready: bool) -> int:
    """The inverse of `decode_state_word_2` (the simulator builds 2101H with it)."""
    if state.ready is None:
        raise ValueError("state word 2: a drive is either ready or not")
    source = CommandSource[state.command_source.upper()]
    value = _READY_BIT if state.ready == ready_bit_set_means_ready else 0
    value |= ((state.motor - 1) & 0b11) << _MOTOR_SHIFT
    value |= _SYNCHRONOUS_BIT if state.synchronous_motor else 0
    value |= _OVERLOAD_PRE_ALARM_BIT if state.overload_pre_alarm else 0
    return value | (int(source) << _SOURCE_SHIFT)
