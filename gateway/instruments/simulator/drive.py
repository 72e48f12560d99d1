"""One simulated INVT drive: request PDU in, reply PDU out. Pure logic, no I/O, no clock.

Every call takes `now` (seconds, any monotonic base) and the drive works out lazily what its
ramp did since the last call. What it answers follows the INVT communication chapters:

- 03H read 1..16 contiguous words; 06H write one; 10H write 1..16; 08H sub-function 0000
  loop-back (the reply equals the request). Any other function code: exception 01H.
- A PDU of the wrong length: 06H "data frame error" (INVT's meaning, not "busy").
- A count of 0 or above 16, or a 10H byte count that disagrees with it: 03H "illegal data value"
  (the manual: "an error of the remaining structure in the combined request").
- An address that isn't there, can't be read (2000H, 8xxxH) or belongs to the manufacturer group:
  02H. A read-only parameter written: 07H. A "◎" parameter written while running: 08H.
  A value outside its range: 04H "operation failure" (P00.01 = 3 → 01 86 04 43 A3).
- A run or jog command while the drive is faulty: 01H ("the slave is in the faulty state").
"""

from __future__ import annotations

import functools
import math
import random
import struct
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from enum import Enum
from typing import Final

from gateway.errors import RequestRefused
from gateway.instruments.simulator.motor import Ramp, RampPhase
from gateway.modbus.functions import (
    DIAGNOSTICS,
    READ_HOLDING_REGISTERS,
    WRITE_MULTIPLE_REGISTERS,
    WRITE_SINGLE_REGISTER,
    exception_pdu,
)
from gateway.profile import exception_codes as exc
from gateway.profile.addressing import RAM_BIT, parse_parameter
from gateway.profile.faults import COMMUNICATION_FAULT, NO_FAULT
from gateway.profile.invt import InvtProfile
from gateway.profile.models import get_profile
from gateway.profile.parameters import FAULT_HISTORY, Parameter
from gateway.profile.registers import COMMUNICATION_REGISTERS, Register, register_at, to_signed
from gateway.profile.states import (
    CommandSource,
    ControlCommand,
    RunState,
    StateWord2,
    encode_state_word_2,
)

SIMULATOR_DEFAULTS: Final = {"P00.01": 2, "P00.06": 8}
"""Commissioned for remote control: run commands (P00.01 = 2) and frequency (P00.06 = 8) come
from Modbus. The factory defaults (0: keypad) would make every drive ignore the gateway."""

LOOP_BACK: Final = b"\x00\x00"
CONTROL_WORD: Final = 0x2000
MODBUS_FREQUENCY_SOURCE: Final = 8
KEYPAD_FREQUENCY_SOURCE: Final = 0
REVERSE_FORBIDDEN: Final = 2


class Mode(Enum):
    STOPPED = "stopped"
    RUNNING = "running"
    JOGGING = "jogging"
    STOPPING = "stopping"
    FAULT = "fault"


@dataclass(frozen=True)
class Nameplate:
    """The motor and supply the running values are made plausible for: 380 V 4-pole 50 Hz."""

    rated_voltage_v: float = 380.0
    rated_current_a: float = 10.0
    base_frequency_hz: float = 50.0
    pole_pairs: int = 2
    rated_slip: float = 0.03
    bus_voltage_v: float = 540.0


_STORED_REGISTERS: Final = tuple(
    register for register in COMMUNICATION_REGISTERS if register.writable and register.readable
)


class SimulatedDrive:
    def __init__(
        self,
        address: int,
        model: str = "gd350",
        *,
        fault_history: Sequence[int] = (),
        parameters: Mapping[str, int] | None = None,
        nameplate: Nameplate | None = None,
    ) -> None:
        if not 1 <= address <= 247:
            raise ValueError(f"drive address {address} is outside 1..247")
        self.address = address
        profile = get_profile(model)
        if not isinstance(profile, InvtProfile):
            raise ValueError(f"{model!r} is not an INVT model: this simulated drive is INVT's")
        self.profile = profile
        self.nameplate = nameplate or Nameplate()
        self._parameters = {spec.address: spec.default for spec in self.profile.parameters}
        self._parameters[parse_parameter("P14.00")] = address
        for name, raw in {**SIMULATOR_DEFAULTS, **(parameters or {})}.items():
            self._set_initial_parameter(name, raw)
        self._registers = {register.address: 0 for register in _STORED_REGISTERS}
        self._live_addresses = frozenset(
            [*_STATUS_REGISTERS, *_RUNNING_REGISTERS, *self.profile.fault_registers]
        )
        self._mode = Mode.STOPPED
        self._direction = 1
        self._jog_ramp = False
        self._fault = NO_FAULT
        self._ramp = Ramp()
        self._last_request_at: float | None = None
        self.eeprom_writes = 0
        """Parameter words written to EEPROM (a plain Pxx.yy address)."""
        self.ram_writes = 0
        """Parameter words written to RAM only (8xxxH): these don't wear the EEPROM."""
        self.written_parameters: set[str] = set()
        self.output_current: tuple[float, float] | None = None
        """(amps, jitter) a test set (`set_output_current`); None: what the motor draws."""
        self.set_fault_history(fault_history)

    # ----------------------------------------------------------------- requests

    def handle(self, pdu: bytes, now: float) -> bytes:
        """The reply PDU to a request PDU addressed to this drive (an exception PDU if refused)."""
        self._check_communication_timeout(now)
        self._last_request_at = now
        self._advance(now)
        function = pdu[0] if pdu else 0
        try:
            if function == READ_HOLDING_REGISTERS:
                return self._read(pdu, now)
            if function == WRITE_SINGLE_REGISTER:
                return self._write_single(pdu, now)
            if function == WRITE_MULTIPLE_REGISTERS:
                return self._write_multiple(pdu, now)
            if function == DIAGNOSTICS:
                return self._diagnose(pdu)
            raise RequestRefused(exc.ILLEGAL_COMMAND, f"function {function:#04x} not supported")
        except RequestRefused as refused:
            return exception_pdu(function, refused.code)

    def apply_broadcast(self, pdu: bytes, now: float) -> None:
        """Act on a broadcast (address 0): writes only, and never an answer."""
        if pdu and pdu[0] in (WRITE_SINGLE_REGISTER, WRITE_MULTIPLE_REGISTERS):
            self.handle(pdu, now)

    def _read(self, pdu: bytes, now: float) -> bytes:
        start, count = _unpack_header(pdu, expected_length=5)
        self._check_count(count)
        _check_span(start, count)
        span = range(start, start + count)
        # Computed only for a read that asks for one: they are most of a read's work, and a
        # bench of 32 lines asks its drives for set-points thousands of times a second.
        live = {} if self._live_addresses.isdisjoint(span) else self._live_values(now)
        words = [self._read_word(address, live) for address in span]
        return bytes((READ_HOLDING_REGISTERS, 2 * count)) + struct.pack(f">{count}H", *words)

    def _write_single(self, pdu: bytes, now: float) -> bytes:
        address, value = _unpack_header(pdu, expected_length=5)
        self._write([(address, value)], now)
        return pdu

    def _write_multiple(self, pdu: bytes, now: float) -> bytes:
        if len(pdu) < 6 or len(pdu) != 6 + pdu[5]:
            raise RequestRefused(exc.DATA_FRAME_ERROR, f"10H request of {len(pdu)} bytes")
        start, count = struct.unpack_from(">HH", pdu, 1)
        self._check_count(count)
        if pdu[5] != 2 * count:
            raise RequestRefused(exc.ILLEGAL_DATA_VALUE, f"byte count {pdu[5]} for {count} words")
        _check_span(start, count)
        if start & RAM_BIT and not self.profile.ram_writes_via_10h:
            raise RequestRefused(exc.ILLEGAL_DATA_ADDRESS, "10H to a RAM-only address")
        values = struct.unpack_from(f">{count}H", pdu, 6)
        self._write(zip(range(start, start + count), values, strict=True), now)
        return pdu[:5]

    def _diagnose(self, pdu: bytes) -> bytes:
        if len(pdu) != 5:
            raise RequestRefused(exc.DATA_FRAME_ERROR, f"08H request of {len(pdu)} bytes")
        if pdu[1:3] != LOOP_BACK:
            # Only "return data based on query requests" (0000) is documented.
            raise RequestRefused(exc.ILLEGAL_COMMAND, f"08H sub-function {pdu[1:3].hex()}")
        return pdu

    def _check_count(self, count: int) -> None:
        if not 1 <= count <= self.profile.max_words:
            raise RequestRefused(
                exc.ILLEGAL_DATA_VALUE, f"{count} words (1..{self.profile.max_words})"
            )

    # ----------------------------------------------------------------- reading

    def _read_word(self, address: int, live: Mapping[int, int]) -> int:
        if address & RAM_BIT:
            raise RequestRefused(exc.ILLEGAL_DATA_ADDRESS, "RAM-only addresses are write-only")
        spec = self._parameter_spec(address)
        if spec is not None:
            return self._parameters[spec.address]
        if address in self._registers:
            return self._registers[address]
        if address in self._live_addresses:
            return live[address]
        raise RequestRefused(exc.ILLEGAL_DATA_ADDRESS, f"{address:04X}H cannot be read")

    def _live_values(self, now: float) -> dict[int, int]:
        """State words, fault code, identification and running values (3000H-3016H)."""
        plate = self.nameplate
        frequency = abs(self._ramp.frequency_hz)
        phase = self._ramp.phase(self._target_hz())
        turning = frequency > 0 or self._mode in (Mode.RUNNING, Mode.JOGGING)
        # A fan-like load: torque rises with the square of speed; ramps add or take torque.
        speed_ratio = frequency / plate.base_frequency_hz
        load_pct = min(15.0 + 65.0 * speed_ratio**2, 100.0)
        torque_pct = 0.0
        if turning:
            torque_pct = (
                load_pct
                + {
                    RampPhase.ACCELERATING: 50.0,
                    RampPhase.DECELERATING: -60.0,
                    RampPhase.STEADY: 0.0,
                }[phase]
            )
        power_pct = torque_pct * speed_ratio
        current_a = plate.rated_current_a * (0.3 + 0.7 * min(abs(torque_pct), 150.0) / 100.0)
        bus_v = plate.bus_voltage_v - 0.05 * power_pct
        if phase is RampPhase.DECELERATING:
            bus_v += 25.0  # energy flowing back from the motor lifts the DC bus
        if self.output_current is not None:
            amps, jitter = self.output_current
            current_a = amps + random.uniform(-jitter, jitter)
        rpm = frequency * 60.0 / plate.pole_pairs * (1.0 - plate.rated_slip * load_pct / 100.0)
        identification = self.identification
        values = {
            0x2100: self._state_word_1(),
            0x2101: self._state_word_2(),
            0x2102: self._fault,
            0x2103: identification,
            0x3000: round(frequency * 100),
            0x3001: round(abs(self._setting_hz()) * 100),
            0x3002: round(bus_v * 10),
            0x3003: round(plate.rated_voltage_v * min(speed_ratio, 1.0)) if turning else 0,
            0x3004: round(current_a * 10) if turning or self.output_current else 0,
            0x3005: round(rpm),
            0x3006: round(power_pct * 10) & 0xFFFF,
            0x3007: round(torque_pct * 10) & 0xFFFF,
            0x3008: self._registers[0x2002],
            0x3009: self._registers[0x2003],
            # 300AH-3014H: terminals, analogue and pulse inputs, steps: nothing is wired.
            **dict.fromkeys(range(0x300A, 0x3015), 0),
            0x3015: self._registers[0x2004],
            0x3016: identification,
        }
        for register in self.profile.fault_registers:
            values[register] = self._fault
        return values

    def _state_word_1(self) -> int:
        if self._mode is Mode.FAULT:
            return RunState.FAULT
        if self._mode is Mode.STOPPED:
            return RunState.STOPPED
        return RunState.RUNNING_FORWARD if self._direction > 0 else RunState.RUNNING_REVERSE

    def _state_word_2(self) -> int:
        state = StateWord2(
            ready=self._mode is not Mode.FAULT,
            motor=1,
            synchronous_motor=False,
            overload_pre_alarm=False,
            command_source=CommandSource(self._parameter("P00.01")).name.lower(),
        )
        return encode_state_word_2(state, self.profile.ready_bit_set_means_ready)

    # ----------------------------------------------------------------- writing

    def _write(self, items: Iterable[tuple[int, int]], now: float) -> None:
        """Check every word, then apply them all: a refused 10H changes nothing."""
        parameters = dict(self._parameters)
        registers = dict(self._registers)
        commands: list[ControlCommand] = []
        ram_words = eeprom_words = 0
        written: list[str] = []
        for address, value in items:
            spec = self._parameter_spec(address)
            if spec is not None:
                if address & RAM_BIT and not self.profile.ram_writes_supported:
                    raise RequestRefused(exc.ILLEGAL_DATA_ADDRESS, "RAM-only writes not supported")
                self._check_parameter_write(spec, value, parameters)
                if parameters[spec.address] != value:
                    # As the manual says: a new rated motor power (P02.01) re-initialises
                    # P02.02-P02.10; later words of the same 10H write still land.
                    for name in spec.reinitialises:
                        reset = self.profile.parameter_table.named(name)
                        if reset is not None:
                            parameters[reset.address] = reset.default
                parameters[spec.address] = value
                written.append(spec.name)
                if address & RAM_BIT:
                    ram_words += 1
                else:
                    eeprom_words += 1
                continue
            register = register_at(address)
            if register is None or not register.writable:
                if address in self._live_addresses:
                    raise RequestRefused(exc.PARAMETER_READ_ONLY, f"{address:04X}H is read-only")
                raise RequestRefused(exc.ILLEGAL_DATA_ADDRESS, f"{address:04X}H cannot be written")
            self._check_register_write(register, value, parameters)
            if address == CONTROL_WORD:
                commands.append(self._check_command(value))
            else:
                registers[address] = value
        self._parameters = parameters
        self._registers = registers
        self.ram_writes += ram_words
        self.eeprom_writes += eeprom_words
        self.written_parameters.update(written)
        for command in commands:
            self._command(command, now)

    def _check_parameter_write(
        self, spec: Parameter, value: int, parameters: Mapping[int, int]
    ) -> None:
        if spec.read_only:
            raise RequestRefused(exc.PARAMETER_READ_ONLY, f"{spec.name} is read-only")
        if spec.locked_while_running and self._mode in _OUTPUT_ACTIVE:
            raise RequestRefused(
                exc.NOT_CHANGEABLE_WHILE_RUNNING, f"{spec.name} is locked while running"
            )
        low = self._bound(spec.minimum_from, parameters, spec.minimum)
        high = self._bound(spec.maximum_from, parameters, spec.maximum)
        number = spec.number(value)
        if not low <= number <= high:
            raise RequestRefused(
                exc.OPERATION_FAILURE, f"{spec.name} = {number} outside {low}..{high}"
            )

    def _bound(self, name: str | None, parameters: Mapping[int, int], fixed: int) -> int:
        """A range bound: another parameter's value (P00.04 <= P00.03), or the fixed one."""
        if name is None:
            return fixed
        bound = self.profile.parameter_table.named(name)
        if bound is None:
            return fixed
        return bound.number(parameters[bound.address])

    def _check_register_write(
        self, register: Register, value: int, parameters: Mapping[int, int]
    ) -> None:
        number = to_signed(value) if register.signed else value
        low = register.minimum if register.minimum is not None else -0x8000
        high = register.maximum if register.maximum is not None else 0xFFFF
        if register.maximum_from is not None:
            high = parameters[parse_parameter(register.maximum_from)]
        if register.name == "virtual_input_terminals":
            high = (1 << self.profile.virtual_input_bits) - 1
        if not low <= number <= high:
            raise RequestRefused(
                exc.OPERATION_FAILURE, f"{register.name} = {number} outside {low}..{high}"
            )

    def _check_command(self, value: int) -> ControlCommand:
        command = ControlCommand(value)  # the range was checked against the register map
        starts = command in _STARTING_COMMANDS
        if starts and self._mode is Mode.FAULT:
            raise RequestRefused(exc.ILLEGAL_COMMAND, "the drive is faulty: reset the fault first")
        return command

    def _command(self, command: ControlCommand, now: float) -> None:
        if command is ControlCommand.FAULT_RESET:
            self.clear_fault(now)
            return
        if self._parameter("P00.01") != CommandSource.COMMUNICATION:
            # Keypad or terminals own the run commands: the write is accepted and ignored.
            return
        if command in (ControlCommand.RUN_FORWARD, ControlCommand.RUN_REVERSE):
            self._start(Mode.RUNNING, command is ControlCommand.RUN_FORWARD)
        elif command in (ControlCommand.JOG_FORWARD, ControlCommand.JOG_REVERSE):
            if self._mode is not Mode.RUNNING:  # a running drive doesn't switch to jog
                self._start(Mode.JOGGING, command is ControlCommand.JOG_FORWARD)
        elif command is ControlCommand.STOP:
            if self._mode in (Mode.RUNNING, Mode.JOGGING):
                self._mode = Mode.STOPPING
        elif command is ControlCommand.JOG_STOP:
            if self._mode is Mode.JOGGING:
                self._mode = Mode.STOPPING
        elif command is ControlCommand.COAST_STOP and self._mode is not Mode.FAULT:
            self._ramp.coast(now)
            self._mode = Mode.STOPPED

    def _start(self, mode: Mode, forward: bool) -> None:
        direction = 1 if forward else -1
        if self._parameter("P00.13") == 1:
            direction = -direction  # P00.13 = 1: the motor's direction is reversed
        if direction < 0 and self._parameter("P00.13") == REVERSE_FORBIDDEN:
            return
        self._mode = mode
        self._direction = direction
        self._jog_ramp = mode is Mode.JOGGING

    # ----------------------------------------------------------------- ramp

    def _advance(self, now: float) -> None:
        accel, decel = self._ramp_rates()
        self._ramp.advance(now, self._target_hz(), accel, decel)
        if self._mode is Mode.STOPPING and self._ramp.frequency_hz == 0:
            self._mode = Mode.STOPPED

    def _ramp_rates(self) -> tuple[float, float]:
        """Hz/s: P00.03 over the acceleration / deceleration time (P08.07/P08.08 for jog)."""
        up, down = ("P08.07", "P08.08") if self._jog_ramp else ("P00.11", "P00.12")
        max_hz = self._parameter("P00.03") / 100

        def rate(name: str) -> float:
            seconds = self._parameter(name) / 10
            return max_hz / seconds if seconds else math.inf

        return rate(up), rate(down)

    def _target_hz(self) -> float:
        if self._mode in (Mode.RUNNING, Mode.JOGGING):
            return self._direction * self._setting_hz()
        return 0.0

    def _setting_hz(self) -> float:
        """What the drive runs at when running: the jog frequency, or the reference clamped to
        the lower (P00.05) and upper (P00.04) limits."""
        if self._mode is Mode.JOGGING:
            return min(self._parameter("P08.06"), self._parameter("P00.03")) / 100
        source = self._parameter("P00.06")
        if source == MODBUS_FREQUENCY_SOURCE:
            reference = self._registers[0x2001]
        elif source == KEYPAD_FREQUENCY_SOURCE:
            reference = self._parameter("P00.10")
        else:
            reference = 0  # analogue inputs, pulse inputs, PLC...: nothing is wired
        low, high = self._parameter("P00.05"), self._parameter("P00.04")
        return max(low, min(reference, high)) / 100

    def _check_communication_timeout(self, now: float) -> None:
        """P14.04 > 0: no request for that long raises fault CE (18), at the moment it expired."""
        timeout_s = self._parameter("P14.04") / 10
        last = self._last_request_at
        expired = timeout_s and last is not None and now - last > timeout_s
        if expired and last is not None and self._mode is not Mode.FAULT:
            self.inject_fault(COMMUNICATION_FAULT, last + timeout_s)

    def set_output_current(self, amps: float | None, jitter_a: float = 0.0) -> None:
        """3004H reads `amps`, each read moved by up to ±`jitter_a` at random, running or not
        (as a current transformer's noise does); None: what the motor draws again."""
        self.output_current = None if amps is None else (amps, abs(jitter_a))

    # ----------------------------------------------------------------- faults

    def inject_fault(self, code: int, now: float | None = None) -> None:
        """Trip: state 4, 2102H = code, the motor coasts, the fault history shifts."""
        if not 1 <= code <= 0xFFFF:
            raise ValueError(f"fault code {code} must be 1..65535 (0 means no fault)")
        moment = time.monotonic() if now is None else now
        self._advance(moment)
        self._ramp.coast(moment)
        self._mode = Mode.FAULT
        self._fault = code
        self.set_fault_history([code, *self.fault_history[:-1]])

    def clear_fault(self, now: float | None = None) -> None:
        """What a fault reset (control word 7) does: a faulty drive becomes stopped."""
        self._advance(time.monotonic() if now is None else now)
        if self._mode is Mode.FAULT:
            self._mode = Mode.STOPPED
            self._fault = NO_FAULT

    def set_fault_history(self, codes: Sequence[int]) -> None:
        """P07.27-P07.32, newest first; missing entries are 0 (no fault)."""
        if len(codes) > len(FAULT_HISTORY):
            raise ValueError(f"at most {len(FAULT_HISTORY)} faults are kept, got {len(codes)}")
        padded = [*codes, *[NO_FAULT] * (len(FAULT_HISTORY) - len(codes))]
        for name, code in zip(FAULT_HISTORY, padded, strict=True):
            self._parameters[parse_parameter(name)] = code

    # ----------------------------------------------------------------- looking in

    @property
    def fault_history(self) -> list[int]:
        return [self._parameter(name) for name in FAULT_HISTORY]

    @property
    def identification(self) -> int:
        """What the drive answers at 2103H (and 3016H): 01A0H for a GD350; for a series whose
        code no manual gives (GD30, IPE300), the profile's placeholder, marked unconfirmed."""
        return self.profile.identification[0]

    @property
    def fault_code(self) -> int:
        return self._fault

    @property
    def response_delay_ms(self) -> int:
        """P14.03: the time between the end of a request and the start of the reply."""
        return self._parameter("P14.03")

    def parameter(self, name: str) -> int:
        """The raw value of a parameter ("P00.11")."""
        return self._parameter(name)

    def state(self, now: float) -> RunState:
        self._advance(now)
        return RunState(self._state_word_1())

    def frequency_hz(self, now: float) -> float:
        """The output frequency, negative in reverse."""
        self._advance(now)
        return self._ramp.frequency_hz

    def _parameter(self, name: str) -> int:
        return self._parameters[_register_of(name)]

    def _parameter_spec(self, address: int) -> Parameter | None:
        plain = address & ~RAM_BIT
        if plain >> 8 == self.profile.manufacturer_group:
            return None  # the manufacturer's group can be neither read nor written
        return self.profile.parameter_table.at(plain)

    def _set_initial_parameter(self, name: str, raw: int) -> None:
        spec = self.profile.parameter_table.named(name)
        if spec is None:
            raise ValueError(f"{name} is not a simulated parameter")
        if not spec.minimum <= spec.number(raw) <= spec.maximum:
            raise ValueError(f"{name} = {raw} is outside {spec.minimum}..{spec.maximum}")
        self._parameters[spec.address] = raw


_STATUS_REGISTERS: Final = range(0x2100, 0x2104)
_RUNNING_REGISTERS: Final = range(0x3000, 0x3017)
_OUTPUT_ACTIVE: Final = (Mode.RUNNING, Mode.JOGGING, Mode.STOPPING)
_STARTING_COMMANDS: Final = frozenset(
    {
        ControlCommand.RUN_FORWARD,
        ControlCommand.RUN_REVERSE,
        ControlCommand.JOG_FORWARD,
        ControlCommand.JOG_REVERSE,
    }
)


def _unpack_header(pdu: bytes, expected_length: int) -> tuple[int, int]:
    """(address, count or value) of a fixed-length request; 06H when the length is wrong."""
    if len(pdu) != expected_length:
        raise RequestRefused(exc.DATA_FRAME_ERROR, f"request of {len(pdu)} bytes")
    first, second = struct.unpack_from(">HH", pdu, 1)
    return int(first), int(second)


def _check_span(start: int, count: int) -> None:
    if start + count > 0x10000:
        raise RequestRefused(exc.ILLEGAL_DATA_ADDRESS, "the block runs past FFFFH")


@functools.cache
def _register_of(name: str) -> int:
    """`parse_parameter`, remembered: the ramp asks for the same few names on every request."""
    return parse_parameter(name)
