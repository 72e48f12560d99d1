"""What a drive command means in registers: INVT's command semantics, as plain data. No I/O.

A dashboard says "run forward at 35 Hz", "set 35 Hz", or "P00.11 = 10.0 s, in RAM only"; this
module says which words go to which registers (the MQTT bridge reads the payload, the router
carries the write):

- a control command is one word to the control word (2000H);
- a set-point alone is one word to the frequency set-point (2001H), in 0.01 Hz;
- a command with a set-point is one 10H write of 2000H-2001H: both reach the drive together, so
  the drive never runs at the old set-point first;
- a parameter written "RAM only" goes to its RAM twin (P00.11 → 800BH), sparing the EEPROM.

Each refusal is a `ValueError` whose message names the problem; the caller says which kind of
refusal it is.
"""

from __future__ import annotations

from typing import Final

from gateway.profile.addressing import RAM_BIT, is_parameter_register, is_ram_address
from gateway.profile.parameters import Parameter, parameter_at
from gateway.profile.protocol import DriveProfile, RegisterWrite
from gateway.profile.ram_writes import ram_write_address
from gateway.profile.registers import register_at, register_by_name
from gateway.profile.states import ControlCommand

CONTROL_WORD: Final = register_by_name("control_word")
FREQUENCY_SETPOINT: Final = register_by_name("frequency_setpoint")


def setpoint_word(frequency_hz: float) -> int:
    """The set-point register's word for `frequency_hz` (0.01 Hz). Raises ValueError."""
    return FREQUENCY_SETPOINT.encode(frequency_hz)


def control_write(command: ControlCommand | None, setpoint: int | None) -> RegisterWrite:
    """A control command, a set-point word (from `setpoint_word`), or both in one write."""
    if command is None:
        if setpoint is None:
            raise ValueError("nothing to write: a command, a set-point, or both")
        return RegisterWrite(FREQUENCY_SETPOINT.address, (setpoint,))
    if setpoint is None:
        return RegisterWrite(CONTROL_WORD.address, (int(command),))
    # 2000H and 2001H are neighbours: one 10H write of both, the command and its set-point.
    return RegisterWrite(CONTROL_WORD.address, (int(command), setpoint))


def ram_only_address(address: int, spelled: str, profile: DriveProfile) -> int:
    """Where a "RAM only" write of `address` goes. Raises ValueError when it has no RAM twin."""
    if not profile.ram_writes_supported:
        raise ValueError(f"{profile.display_name} has no RAM-only writes")
    # The profile's one rule, the same the router applies to a drive with `ram_writes: true`
    # (which then leaves this address alone: it is already the RAM-only one).
    ram = ram_write_address(address)
    if not is_ram_address(ram):
        raise ValueError(f"{spelled} is not a parameter: no RAM-only write")
    return ram


def known_decimals(address: int, profile: DriveProfile | None = None) -> int | None:
    """The decimals of a communication register or a known parameter (or its RAM twin): the
    drive's series table when `profile` is given, else the common table."""
    communication = register_at(address)
    if communication is not None:
        return communication.decimals
    known = _parameter(address, profile)
    return None if known is None else known.decimals


def is_signed(address: int, profile: DriveProfile | None = None) -> bool:
    """Whether the word is a two's-complement number (a signed running value, or a parameter
    whose range goes below 0 in the drive's series table)."""
    communication = register_at(address)
    if communication is not None:
        return communication.signed
    known = _parameter(address, profile)
    return known is not None and known.signed


def _parameter(address: int, profile: DriveProfile | None) -> Parameter | None:
    if not is_parameter_register(address):
        return None
    if profile is not None:
        return profile.parameter_table.at(address & ~RAM_BIT)
    return parameter_at(address & ~RAM_BIT)
