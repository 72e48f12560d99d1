"""A simulated ABB drive (ACS355, ACS580) on the ABB Drives profile: 40001-40012 and the control
word's state machine, as `gateway/profile/data/abb_drives.yaml` cites them.

The state machine (ACS355 manual, page 319), reduced to what a master sees:
- power on: SWITCH-ON INHIBITED; a control word with OFF1 (bit 0) = 0 and OFF2, OFF3 (bits 1,
  2) = 1 gets READY TO SWITCH ON (from any running state too: OFF1 is the ramp stop);
- then OFF1 = 1: READY TO OPERATE, and with bit 3 (run) OPERATION ENABLED, running at
  reference 1 (negative: reverse). A step away from READY TO SWITCH ON sooner than 100 ms after
  it was reached is ignored ("Wait at least 100 ms before proceeding": a master that doesn't
  wait sees its drive stay put);
- OFF2 or OFF3 = 0: SWITCH-ON INHIBITED; a fault: TRIPPED until bit 7 rises.
Functions 03H, 06H and 10H; anything else is refused with 01H (no 08H loop-back here).
"""

from __future__ import annotations

import struct
from enum import IntEnum
from typing import Final

from gateway.errors import RequestRefused
from gateway.modbus.functions import (
    READ_HOLDING_REGISTERS,
    WRITE_MULTIPLE_REGISTERS,
    WRITE_SINGLE_REGISTER,
    exception_pdu,
)
from gateway.profile import exception_codes as code
from gateway.profile.abb import (
    ABB_PROFILES,
    ACTUAL_VALUES,
    CONTROL_WORD,
    REFERENCE_1,
    REFERENCE_2,
    STATUS_WORD,
    AbbProfile,
)
from gateway.profile.states import RunState

ABB_MODELS: Final = frozenset(ABB_PROFILES)
WRITABLE: Final = frozenset({CONTROL_WORD, REFERENCE_1, REFERENCE_2})
LAST: Final = ACTUAL_VALUES[-1]
READY_DELAY_S: Final = 0.1
"""READY TO SWITCH ON is not ready for the next step sooner (ACS550-02/U2 manual, page 246):
the drive's own time, not the profile's pause, so a profile that didn't wait is caught."""

_OFF1, _OFF2, _OFF3, _RUN, _RESET = 1 << 0, 1 << 1, 1 << 2, 1 << 3, 1 << 7


class Machine(IntEnum):
    SWITCH_ON_INHIBITED = 0
    READY_TO_SWITCH_ON = 1
    READY_TO_OPERATE = 2
    OPERATION_ENABLED = 3


class SimulatedAbbDrive:
    def __init__(self, address: int, model: str) -> None:
        if not 1 <= address <= 247:
            raise ValueError(f"drive address {address} is outside 1..247")
        self.address = address
        self.profile: AbbProfile = ABB_PROFILES[model]
        self.words = dict.fromkeys(range(LAST + 1), 0)
        self.machine = Machine.SWITCH_ON_INHIBITED
        self.tripped = False
        self._entered_at = 0.0
        self.written_parameters: set[str] = set()  # none: its response delay is the line's
        self.response_delay_ms = 0

    def state(self, now: float) -> RunState:
        """The gateway's reading of it, for tests: running by reference 1's sign."""
        if self.tripped:
            return RunState.FAULT
        if self.machine is Machine.OPERATION_ENABLED:
            reverse = self.words[REFERENCE_1] & 0x8000
            return RunState.RUNNING_REVERSE if reverse else RunState.RUNNING_FORWARD
        return RunState.STOPPED

    def handle(self, pdu: bytes, now: float) -> bytes:
        function = pdu[0] if pdu else 0
        try:
            if function == READ_HOLDING_REGISTERS and len(pdu) == 5:
                start, count = struct.unpack_from(">HH", pdu, 1)
                self._check(start, count)
                words = [self._word(address) for address in range(start, start + count)]
                return bytes((function, 2 * count)) + struct.pack(f">{count}H", *words)
            if function == WRITE_SINGLE_REGISTER and len(pdu) == 5:
                address, value = struct.unpack_from(">HH", pdu, 1)
                self._write(address, (value,), now)
                return pdu
            if function == WRITE_MULTIPLE_REGISTERS and len(pdu) >= 6:
                start, count = struct.unpack_from(">HH", pdu, 1)
                values = struct.unpack_from(f">{count}H", pdu, 6)
                self._write(start, values, now)
                return pdu[:5]
        except RequestRefused as refused:
            return exception_pdu(function, refused.code)
        except struct.error:
            return exception_pdu(function, code.ILLEGAL_DATA_VALUE)
        return exception_pdu(function, code.ILLEGAL_COMMAND)

    def apply_broadcast(self, pdu: bytes, now: float) -> None:
        if pdu and pdu[0] in (WRITE_SINGLE_REGISTER, WRITE_MULTIPLE_REGISTERS):
            self.handle(pdu, now)

    def inject_fault(self, fault: int, now: float) -> None:
        self.tripped = True
        self.machine = Machine.SWITCH_ON_INHIBITED

    def clear_fault(self, now: float) -> None:
        self.tripped = False

    def set_fault_history(self, codes: object) -> None:
        raise ValueError("an ABB drive keeps no P07.27 fault history")

    # -- the registers ----------------------------------------------------------------------
    def _check(self, start: int, count: int) -> None:
        if not 1 <= count <= 125 or start + count > LAST + 1:
            raise RequestRefused(code.ILLEGAL_DATA_ADDRESS, "outside 40001-40012")

    def _word(self, address: int) -> int:
        if address == STATUS_WORD:
            return self._status_word()
        if address == ACTUAL_VALUES[0]:  # a copy of speed or frequency (58.28 Auto)
            running = self.machine is Machine.OPERATION_ENABLED
            return self.words[REFERENCE_1] if running else 0
        return self.words[address]

    def _write(self, start: int, values: tuple[int, ...], now: float) -> None:
        addresses = range(start, start + len(values))
        if not values or any(address not in WRITABLE for address in addresses):
            raise RequestRefused(code.ILLEGAL_DATA_ADDRESS, "not a writable register")
        before = self.words[CONTROL_WORD]
        for address, value in zip(addresses, values, strict=True):
            self.words[address] = value
        if CONTROL_WORD in addresses:
            self._step(before, self.words[CONTROL_WORD], now)

    def _step(self, before: int, word: int, now: float) -> None:
        if self.tripped:
            if word & _RESET and not before & _RESET:
                self.tripped = False
                self._enter(Machine.SWITCH_ON_INHIBITED, now)
            return
        if not word & _OFF2 or not word & _OFF3:
            self._enter(Machine.SWITCH_ON_INHIBITED, now)
        elif not word & _OFF1:
            self._enter(Machine.READY_TO_SWITCH_ON, now)
        elif self.machine >= Machine.READY_TO_SWITCH_ON:
            waited = now - self._entered_at
            if self.machine is Machine.READY_TO_SWITCH_ON and waited < READY_DELAY_S:
                return  # not ready yet: the manual's 100 ms
            self._enter(Machine.OPERATION_ENABLED if word & _RUN else Machine.READY_TO_OPERATE, now)

    def _enter(self, machine: Machine, now: float) -> None:
        if machine is not self.machine:
            self.machine = machine
            self._entered_at = now

    def _status_word(self) -> int:
        word = 1 << 9  # REMOTE: the line controls it
        control = self.words[CONTROL_WORD]
        word |= (1 << 4) if control & _OFF2 else 0
        word |= (1 << 5) if control & _OFF3 else 0
        if self.tripped:
            return word | (1 << 3)
        if self.machine is Machine.SWITCH_ON_INHIBITED:
            return word | (1 << 6)
        word |= 1 << 0  # READY TO SWITCH ON
        if self.machine >= Machine.READY_TO_OPERATE:
            word |= 1 << 1
        if self.machine is Machine.OPERATION_ENABLED:
            word |= (1 << 2) | (1 << 8)  # operation enabled, at set-point (no ramp here)
        return word
