"""ABB drives (ACS355, ACS580) on the ABB Drives profile: one `DriveProfile` implementation.

The facts are in `data/abb_drives.yaml`, each with the manual page it comes from: the registers
(40001 control word, 40002 reference 1, 40004 status word, 40005-40012 actual values), the
control words the profile's state machine walks through, and the status word's bits.

What the gateway's words mean here:
- `state` (the words MQTT and the console use for every drive): "fault" when TRIPPED (bit 3);
  "running_forward" / "running_reverse" when OPERATION ENABLED (bit 2), by reference 1's sign
  (the profile runs in reverse on a negative reference); else "stopped".
- `ready`: READY TO OPERATE (bit 1); `command_source`: "remote" or "local" (bit 9).
- a command is a sequence of control words, written in order, with the manual's pause after
  READY TO SWITCH ON; `run_reverse` writes the reference negated, so it needs a set-point.
- the fault code is not among these registers: a fault shows in `state` and `status_word`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib import resources
from typing import Any, Final

import yaml

from gateway.profile.addressing import format_register, parse_register
from gateway.profile.exception_codes import STANDARD_EXCEPTIONS, ExceptionNames
from gateway.profile.faults import FaultTable
from gateway.profile.overrides import FaultOverrides
from gateway.profile.parameter_tables import ParameterTable
from gateway.profile.parameters import Parameter
from gateway.profile.point_types import TypedPoint, no_typed_points
from gateway.profile.points import Point, Profile
from gateway.profile.protocol import Identified, PollGroup, Question, RegisterWrite
from gateway.profile.registers import to_signed
from gateway.profile.telemetry import Telemetry

HOLDING_BASE: Final = 40001
"""The manuals number holding registers from 40001: on the wire that is address 0."""
MODBUS_MAX_WORDS: Final = 125


def _load() -> dict[str, Any]:
    text = resources.files("gateway.profile").joinpath("data", "abb_drives.yaml").read_text()
    data: dict[str, Any] = yaml.safe_load(text)
    return data


_DATA: Final = _load()
_REGISTERS: Final[dict[str, Any]] = _DATA["registers"]
CONTROL_WORD: Final[int] = _REGISTERS["control_word"] - HOLDING_BASE
REFERENCE_1: Final[int] = _REGISTERS["reference_1"] - HOLDING_BASE
REFERENCE_2: Final[int] = _REGISTERS["reference_2"] - HOLDING_BASE
STATUS_WORD: Final[int] = _REGISTERS["status_word"] - HOLDING_BASE
ACTUAL_VALUES: Final = tuple(
    range(
        _REGISTERS["actual_values"][0] - HOLDING_BASE,
        _REGISTERS["actual_values"][1] - HOLDING_BASE + 1,
    )
)
CONTROL_WORDS: Final[dict[str, int]] = dict(_DATA["control_words"])
COMMAND_WORDS: Final[dict[str, tuple[int, ...]]] = {
    command: tuple(CONTROL_WORDS[step] for step in steps)
    for command, steps in _DATA["commands"].items()
}
STATUS_BITS: Final[dict[int, str]] = {
    int(bit): words for bit, words in _DATA["status_bits"].items()
}
FULL_SCALE: Final[int] = _DATA["reference_full_scale"]
STEP_PAUSE_S: Final[float] = _DATA["step_pause_s"]

_TRIPPED: Final = 1 << 3
_OPERATION_ENABLED: Final = 1 << 2
_READY_TO_OPERATE: Final = 1 << 1
_WARNING: Final = 1 << 7
_AT_SETPOINT: Final = 1 << 8
_REMOTE: Final = 1 << 9

STATUS_POLL: Final = PollGroup("status", CONTROL_WORD, ACTUAL_VALUES[-1] + 1, 0.5)
"""40001-40012 in one read: the control word and references as written, the status word, the
actual values."""

_NAMES: Final = {
    "control_word": CONTROL_WORD,
    "reference_1": REFERENCE_1,
    "reference_2": REFERENCE_2,
    "status_word": STATUS_WORD,
    **{f"actual_value_{n}": address for n, address in enumerate(ACTUAL_VALUES, 1)},
}
_BY_ADDRESS: Final = {address: name for name, address in _NAMES.items()}


def status_words(raw: int) -> list[str]:
    """The manual's words for each bit set: ["ready to switch on", "operation enabled", ...]."""
    return [words for bit, words in sorted(STATUS_BITS.items()) if raw & (1 << bit)]


def state(status_word: int, reference_1: int | None) -> str:
    """The gateway's state word for an ABB status word (see the module docstring)."""
    if status_word & _TRIPPED:
        return "fault"
    if status_word & _OPERATION_ENABLED:
        reverse = reference_1 is not None and to_signed(reference_1) < 0
        return "running_reverse" if reverse else "running_forward"
    return "stopped"


def show_status_word(raw: int) -> str:
    """ "0237H (running, direction by reference 1: ready to switch on, ...)", "0230H (stopped:
    ...)": the status word read alone. A running drive's direction is reference 1's sign,
    which `read` and the traffic monitor don't have here, so they don't guess it (the
    telemetry, which has both, says running_forward or running_reverse)."""
    said = state(raw, None)
    if said.startswith("running_"):
        said = "running, direction by reference 1"
    return f"{raw:04X}H ({said}: {', '.join(status_words(raw)) or 'no bit set'})"


@dataclass(frozen=True)
class AbbPoint(Point):
    """A register of the ABB Drives profile: the status word reads in the manual's words."""

    def show(self, raw: int, profile: Profile | None) -> str:
        if self.address == STATUS_WORD:
            return show_status_word(raw & 0xFFFF)
        return f"{to_signed(raw) if self.signed else raw & 0xFFFF}"


@dataclass(frozen=True)
class AbbProfile(FaultOverrides):
    key: str
    display_name: str
    aliases: tuple[str, ...] = ()
    manufacturer: str = "ABB"
    identification: tuple[int, ...] = ()
    """The profile's registers carry no model code: `scan` tells an ABB drive by its status word."""
    unconfirmed: tuple[str, ...] = tuple(_DATA["unconfirmed"])
    max_words: int = MODBUS_MAX_WORDS
    split_by_default: bool = False
    poll_groups: tuple[PollGroup, ...] = (STATUS_POLL,)
    ram_writes_supported: bool = False
    faults: FaultTable = field(default_factory=lambda: FaultTable("ABB Drives profile", {}))
    commands: tuple[str, ...] = tuple(COMMAND_WORDS)
    parameters: tuple[Parameter, ...] = ()
    max_frequency_hz: float = 50.0
    """Reference 1 = 20000 is this frequency (the drive's 46.02 on an ACS580, 1105 on an ACS355)."""
    max_frequency_parameter: Parameter | None = None
    telemetry_keys: frozenset[str] = frozenset(
        {"state", "status_word", "ready", "command_source", "warning", "at_setpoint"}
        | {f"reference_{n}" for n in (1, 2)}
        | {f"actual_value_{n}" for n in range(1, len(ACTUAL_VALUES) + 1)}
    )
    typed_points: tuple[TypedPoint, ...] = ()

    @property
    def parameter_table(self) -> ParameterTable:
        return ParameterTable(self.key, ())

    # -- register words ---------------------------------------------------------------------
    def telemetry(self, registers: Mapping[int, int]) -> Telemetry:
        telemetry: Telemetry = {}
        status = registers.get(STATUS_WORD)
        if status is not None:
            telemetry["state"] = state(status, registers.get(REFERENCE_1))
            telemetry["status_word"] = status
            telemetry["ready"] = bool(status & _READY_TO_OPERATE)
            telemetry["command_source"] = "remote" if status & _REMOTE else "local"
            telemetry["warning"] = bool(status & _WARNING)
            telemetry["at_setpoint"] = bool(status & _AT_SETPOINT)
        for name, address in _NAMES.items():
            if name.startswith(("reference_", "actual_value_")) and address in registers:
                telemetry[name] = to_signed(registers[address])
        return telemetry

    def point(self, address: int) -> Point | None:
        name = _BY_ADDRESS.get(address)
        if name is None:
            return None
        signed = name.startswith(("reference_", "actual_value_"))
        label = str(address + HOLDING_BASE)
        return AbbPoint(label, address, name.replace("_", " "), signed=signed)

    def resolve(self, text: str) -> Point:
        """ "status_word", "40004" (the manual's number), "0x0003" / "0003H" (the address)."""
        spelled = text.strip().lower()
        if spelled in _NAMES:
            return self.point(_NAMES[spelled]) or Point(spelled, _NAMES[spelled])
        if spelled.isdigit() and int(spelled) >= HOLDING_BASE:
            address = int(spelled) - HOLDING_BASE
        else:
            address = parse_register(spelled)
        found = self.point(address)
        if found is not None:
            return found
        return Point(format_register(address), address, "not in the profile: shown raw")

    def point_write(self, name: str, value: object) -> RegisterWrite:
        raise ValueError(no_typed_points(self.display_name))

    # -- faults -----------------------------------------------------------------------------
    @property
    def exceptions(self) -> ExceptionNames:
        """ABB's drives answer the Modbus standard's exceptions (06H: busy)."""
        return STANDARD_EXCEPTIONS

    def current_fault(self, registers: Mapping[int, int]) -> int | None:
        return None  # the fault code is a drive parameter, not one of the profile's words

    def fault_fields(self, code: int) -> Telemetry:
        return {"fault_code": code, "fault_description": self.faults.describe(code)}

    # -- commands ---------------------------------------------------------------------------
    def command_name(self, name: str) -> str:
        key = name.strip().lower().replace("-", "_").replace(" ", "_")
        if key not in COMMAND_WORDS:
            raise ValueError(f"unknown command {name!r}: use one of {', '.join(COMMAND_WORDS)}")
        return key

    def setpoint_word(self, frequency_hz: float) -> int:
        raw = round(frequency_hz / self.max_frequency_hz * FULL_SCALE)
        if not -FULL_SCALE <= raw <= FULL_SCALE:
            raise ValueError(
                f"{frequency_hz} Hz is beyond the reference's full scale "
                f"({self.max_frequency_hz:g} Hz = {FULL_SCALE})"
            )
        return raw & 0xFFFF

    def control_writes(
        self, command: str | None, setpoint: int | None
    ) -> tuple[RegisterWrite, ...]:
        if command is None:
            if setpoint is None:
                raise ValueError("nothing to write: a command, a set-point, or both")
            return (RegisterWrite(REFERENCE_1, (setpoint,)),)
        command = self.command_name(command)
        words = COMMAND_WORDS[command]
        if command == "run_reverse":
            if setpoint is None:
                raise ValueError(
                    "run_reverse on the ABB Drives profile is a negative reference: "
                    "give frequency_hz with it"
                )
            setpoint = -to_signed(setpoint) & 0xFFFF
        steps = [RegisterWrite(CONTROL_WORD, (word,)) for word in words]
        if setpoint is not None:  # 40001-40002 together: the reference arrives with the start
            steps[0] = RegisterWrite(CONTROL_WORD, (words[0], setpoint))
        if len(steps) > 1:  # "wait at least 100 ms" after READY TO SWITCH ON
            steps[0] = RegisterWrite(steps[0].start, steps[0].words, STEP_PAUSE_S)
        return tuple(steps)

    def ram_only_address(self, address: int, spelled: str) -> int:
        raise ValueError(f"{self.display_name} has no RAM-only writes")


def _identified(words: tuple[int, ...]) -> Identified | None:
    """40001-40004 as a scan reads them; the status word's unused bits 13-15 are 0 on an ABB
    drive (ACS320 manual, page 350: "13... 15 Unused"), so a device with them set is not one."""
    status = words[STATUS_WORD]
    if status & 0xE000:
        return None
    names = " or ".join(profile.display_name for profile in ABB_PROFILES.values())
    return Identified(
        model=f"{names} (ABB Drives profile)",
        state=state(status, words[REFERENCE_1]),
        fault="tripped" if status & _TRIPPED else "none",
        command_source="remote" if status & _REMOTE else "local",
    )


SCAN_QUESTION: Final = Question("ABB", CONTROL_WORD, STATUS_WORD + 1, _identified)
"""40001-40004: the control word, the references and the status word in one read."""

ABB_PROFILES: Final[Mapping[str, AbbProfile]] = {
    key: AbbProfile(key, model["display_name"], tuple(model.get("aliases", ())))
    for key, model in _DATA["models"].items()
}
