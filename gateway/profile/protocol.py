"""What the gateway asks of a drive model, whoever makes it: the `DriveProfile` protocol.

Implementations, one module each: `invt.InvtProfile` (every INVT series), `abb.AbbProfile`,
`generic.GenericProfile` (a Modbus device the gateway only carries: raw words, no commands),
`points_device.DeviceProfile` (a device file's typed points: a meter, a transmitter, remote
I/O). `models` is the registry of the names users type (`model:` in the config). Nothing
outside `gateway.profile` asks which maker a drive is: the poller, the MQTT bridge, the settings
and the console ask the profile.

| part | members |
|---|---|
| identification | `key`, `aliases`, `display_name`, `manufacturer`, `identification`, |
| | `unconfirmed`, `with_overrides` |
| the line | `max_words`, `split_by_default`, `poll_groups`, `ram_writes_supported` |
| register words and their decoders | `telemetry`, `telemetry_keys`, `point`, `resolve`, |
| | `typed_points`, `point_write` |
| faults | `faults`, `current_fault`, `fault_fields`, `exceptions` |
| commands | `commands`, `command_name`, `setpoint_word`, `control_writes`, `ram_only_address` |
| parameters | `parameter_table`, `parameters`, `max_frequency_hz`, `max_frequency_parameter` |
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

from gateway.profile.point_types import Table, TypedPoint

if TYPE_CHECKING:
    from gateway.profile.exception_codes import ExceptionNames
    from gateway.profile.faults import FaultTable
    from gateway.profile.parameter_tables import ParameterTable
    from gateway.profile.parameters import Parameter
    from gateway.profile.points import Point
    from gateway.profile.telemetry import Telemetry


@dataclass(frozen=True)
class PollGroup:
    """A block the poller reads from each drive: `count` words (or bits) of `table` from
    `start` every `interval_s`. Its words are kept under `point_types.word_key` (a holding
    register under its bare address)."""

    name: str
    start: int
    count: int
    interval_s: float
    table: Table = Table.HOLDING


@dataclass(frozen=True, slots=True)
class RegisterWrite:
    """Words for the drive from `start` (one word: 06H; several: one 10H write), or a coil's
    state (`table` COIL: one 05H write of words[0], 1 = on)."""

    start: int
    words: tuple[int, ...]
    pause_s: float = 0.0
    """How long to wait after this write before the next one of the same command (a state
    machine that needs time between steps)."""
    table: Table = Table.HOLDING


@dataclass(frozen=True, slots=True)
class Identified:
    """What a maker's identification read says of a drive `scan` found."""

    model: str
    """ "ACS355 or ACS580 (ABB Drives profile)": the words a scan prints."""
    state: str
    """The same state words as the telemetry's `state` ("stopped", "running_forward"...)."""
    fault: str
    command_source: str


@dataclass(frozen=True, slots=True)
class Question:
    """How `scan` asks a drive of one maker what it is: `count` words from `start`, and what
    they say (None: not this maker's drive after all)."""

    maker: str
    start: int
    count: int
    answer: Callable[[tuple[int, ...]], Identified | None]


class DriveProfile(Protocol):
    # -- identification ---------------------------------------------------------------------
    @property
    def key(self) -> str:
        """The name in the config (`gd350`, `acs580`, `generic`)."""

    @property
    def display_name(self) -> str: ...

    @property
    def manufacturer(self) -> str:
        """ "INVT", "ABB"; "" for a device of no known maker."""

    @property
    def aliases(self) -> tuple[str, ...]:
        """Other names users type for this model (normalised as `models.get_profile` does)."""

    @property
    def identification(self) -> tuple[int, ...]:
        """Codes the drive answers when asked its model (empty: it can't be asked)."""

    @property
    def unconfirmed(self) -> tuple[str, ...]:
        """Facts of this profile no public manual confirmed, in words."""

    def with_overrides(
        self,
        *,
        identification: tuple[int, ...] | None = None,
        faults: Mapping[int, str] | None = None,
        ready_bit_set_means_ready: bool | None = None,
    ) -> DriveProfile:
        """This profile with a site's corrections of unconfirmed facts (from the config)."""

    # -- the line ----------------------------------------------------------------------------
    @property
    def max_words(self) -> int:
        """The most words one 03H/10H request may carry."""

    @property
    def split_by_default(self) -> bool:
        """Whether longer requests are split at `max_words` unless the config says otherwise."""

    @property
    def poll_groups(self) -> tuple[PollGroup, ...]: ...

    @property
    def ram_writes_supported(self) -> bool: ...

    # -- register words and their decoders ---------------------------------------------------
    def telemetry(self, registers: Mapping[int, int]) -> Telemetry:
        """The polled words (address → latest word) as the telemetry MQTT and the console show."""

    @property
    def telemetry_keys(self) -> frozenset[str]:
        """Every key `telemetry` can hold (Home Assistant gets sensors for these only)."""

    def point(self, address: int) -> Point | None:
        """The named point at `address`; None: the profile doesn't name it (shown raw)."""

    def resolve(self, text: str) -> Point:
        """The point a person names ("P00.11", "2100H", "output_frequency"). Raises ValueError."""

    @property
    def typed_points(self) -> tuple[TypedPoint, ...]:
        """A device's values as its device file describes them (empty for a drive profile):
        each a telemetry key with its unit and Home Assistant classes."""

    def point_write(self, name: str, value: object) -> RegisterWrite:
        """The write that sets the typed point `name` to `value`. Raises ValueError when there
        is no such point, it isn't writable or the value doesn't fit."""

    # -- faults ------------------------------------------------------------------------------
    @property
    def faults(self) -> FaultTable: ...

    def current_fault(self, registers: Mapping[int, int]) -> int | None:
        """The fault code among the polled words; None: not read (or the device has none)."""

    def fault_fields(self, code: int) -> Telemetry:
        """`fault_code`, `fault_name`, `fault_description` of a fault code."""

    @property
    def exceptions(self) -> ExceptionNames:
        """What the device means by each exception code it answers: its maker's words (INVT's
        own for 04H-09H), the Modbus standard's for a device that follows it. MQTT's answers,
        the console, the poller's log and the field tools all say a device's exception so."""

    # -- commands ----------------------------------------------------------------------------
    @property
    def commands(self) -> tuple[str, ...]:
        """The control commands the drive takes (`run_forward`, `stop`...); empty: none."""

    def command_name(self, name: str) -> str:
        """The command's name as `commands` spells it. Raises ValueError naming the valid ones."""

    def setpoint_word(self, frequency_hz: float) -> int:
        """The set-point's raw word for `frequency_hz`. Raises ValueError when it doesn't fit."""

    def control_writes(
        self, command: str | None, setpoint: int | None
    ) -> tuple[RegisterWrite, ...]:
        """The writes, in order, for a command (from `command_name`), a set-point word (from
        `setpoint_word`), or both. Raises ValueError when the drive can't do it."""

    def ram_only_address(self, address: int, spelled: str) -> int:
        """Where a "RAM only" write of `address` goes. Raises ValueError when there is none."""

    # -- parameters --------------------------------------------------------------------------
    @property
    def parameter_table(self) -> ParameterTable:
        """The series' parameters as the manual lists them (ranges, scales, words), with
        lookups by address and name; empty for a device that has none."""

    @property
    def parameters(self) -> tuple[Parameter, ...]: ...

    @property
    def max_frequency_hz(self) -> float:
        """The set-point maximum until the drive's own is read."""

    @property
    def max_frequency_parameter(self) -> Parameter | None:
        """The parameter holding the drive's own maximum frequency, read once at start."""
