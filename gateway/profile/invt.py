"""INVT drive profiles: what differs between INVT series, as data (`InvtProfile`).

Facts marked **unconfirmed** in the INVT notes are fields here rather than code, so a site can
correct them without a code change (`drives[].identification`, `drives[].faults`,
`drives[].ready_bit_set_means_ready` in the config: see `with_overrides`):
- `identification`: Goodrive30 and IPE300 publish no code at 2103H that we could find (their
  manuals' device-code tables were not reachable; the Goodrive10 and Goodrive300-LIFT tables list
  only 0108H-010DH); their profiles carry a placeholder (`identification_confirmed=False`) that
  the simulator answers and `scan` reports as unconfirmed;
- `faults`: the fault table; Goodrive30, IPE300 and Goodrive300-LIFT have the common Goodrive one,
  unconfirmed (their manuals' fault chapters were not reachable);
- `ready_bit_set_means_ready`: the polarity of 2101H bit 0, which differs by series; the page
  each polarity comes from is in `ready_bit_source` (empty: no page found, the common reading
  "1: ready to run" assumed and listed in `unconfirmed`);
- `decimals_overrides`: the bus-voltage scale (3002H) on GD200A/GD20;
- `ram_writes_via_10h`: whether 10H accepts RAM-only (8xxxH) addresses.

Users name a series by its key (`gd30`, `ipe300`, `gd300l`, `gd350a`...), "Goodrive" for "GD"
(`Goodrive30`) or one of its `aliases` (`gd300lift` for `gd300l`): see `gateway.profile.models`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import Final, TypedDict

from gateway.errors import TableError
from gateway.profile.addressing import format_register
from gateway.profile.commands import control_write, ram_only_address, setpoint_word
from gateway.profile.exception_codes import INVT_EXCEPTIONS, ExceptionNames
from gateway.profile.faults import (
    GD350_FAULTS,
    GOODRIVE_FAULTS,
    UNCONFIRMED_GOODRIVE_FAULTS,
    FaultTable,
)

# INVT's fixed addresses and 2103H names live in `invt_codes` (below the decoders); they are
# named here too (`X as X`), where callers have long found them.
from gateway.profile.invt_codes import (
    FAULT_CODE as FAULT_CODE,
)
from gateway.profile.invt_codes import (
    FAULT_CODE_MIRROR as FAULT_CODE_MIRROR,
)
from gateway.profile.invt_codes import (
    GD30_PLACEHOLDER_CODE as GD30_PLACEHOLDER_CODE,
)
from gateway.profile.invt_codes import (
    IDENTIFICATION as IDENTIFICATION,
)
from gateway.profile.invt_codes import (
    IDENTIFICATION_CODES as IDENTIFICATION_CODES,
)
from gateway.profile.invt_codes import (
    IPE300_PLACEHOLDER_CODE as IPE300_PLACEHOLDER_CODE,
)
from gateway.profile.invt_codes import (
    RUNNING_FREQUENCY as RUNNING_FREQUENCY,
)
from gateway.profile.invt_codes import (
    SERIES_CODES,
    series_keys_for_identification,
)
from gateway.profile.invt_codes import (
    STATE_WORD_1 as STATE_WORD_1,
)
from gateway.profile.invt_codes import (
    describe_identification as describe_identification,
)
from gateway.profile.invt_codes import (
    model_from_identification as model_from_identification,
)
from gateway.profile.parameter_tables import ParameterTable, series_table
from gateway.profile.parameters import Parameter, parameter, parameter_groups
from gateway.profile.point_types import TypedPoint, no_typed_points
from gateway.profile.points import Point, resolve
from gateway.profile.protocol import PollGroup, RegisterWrite
from gateway.profile.states import CONTROL_COMMANDS, control_command
from gateway.profile.telemetry import (
    TELEMETRY_KEYS,
    Telemetry,
    current_fault,
    decode_telemetry,
    fault_fields,
)

MAX_FREQUENCY: Final = "P00.03"
"""Max. output frequency: the set-point maximum Home Assistant shows."""

INVT_MAX_WORDS: Final = 16
"""03H and 10H: "the max. continuous reading is 16 words", contiguous addresses."""


STATE_POLL: Final = PollGroup("state", STATE_WORD_1, 3, 0.5)
"""2100H-2102H: state word 1, state word 2, fault code."""
RUNNING_POLL: Final = PollGroup("running", RUNNING_FREQUENCY, 12, 2.0)
"""3000H-300BH: frequency, voltages, current, speed, power, torque, PID, terminals."""


@dataclass(frozen=True)
class InvtProfile:
    """An INVT series: the `DriveProfile` of every INVT model, its facts as fields."""

    key: str
    display_name: str
    identification: tuple[int, ...] = ()
    """Codes the drive answers at 2103H; the first is the one a simulated drive answers."""
    identification_confirmed: bool = True
    """False: no public manual gives the code; `identification` is a placeholder."""
    aliases: tuple[str, ...] = ()
    """Other names users type for this series (normalised as `get_profile` does)."""
    max_words: int = INVT_MAX_WORDS
    fault_registers: tuple[int, ...] = (FAULT_CODE,)
    poll_groups: tuple[PollGroup, ...] = (STATE_POLL, RUNNING_POLL)
    ram_writes_supported: bool = True
    ram_writes_via_10h: bool = True  # unconfirmed
    manufacturer_group: int | None = None
    """A parameter group that can be neither read nor written (P99 on GD350, P29 on GD10...)."""
    ready_bit_set_means_ready: bool = True
    """2101H bit 0 = 1 means "ready to run" (GD300, GD350, GD30); False where the series' manual
    says "=0: ready for operation" (GD35, GD300-LIFT)."""
    ready_bit_source: str = ""
    """The manual page `ready_bit_set_means_ready` comes from; empty when none was found."""
    decimals_overrides: Mapping[str, int] = field(default_factory=lambda: MappingProxyType({}))
    """Register name → decimals where this model differs from the register map."""
    virtual_input_bits: int = 9
    faults: FaultTable = GOODRIVE_FAULTS
    """The series' own fault list: a code outside it is "unknown fault N" for this drive."""
    motors: int = 4
    """Motors state word 2 (2101H bits 2-1) reports: a GD30's lists 10 and 11 as "reserved".
    2009H bits 1-0 select a motor; every manual's 2009H row, the GD30's included, lists 1-4."""
    max_frequency_hz: float = 50.0
    """P00.03's factory value: the set-point maximum until the drive's own is read."""
    unconfirmed: tuple[str, ...] = ()
    """Facts of this profile no public manual confirmed, in words (docs, `scan`, `decode-fault`)."""
    typed_points: tuple[TypedPoint, ...] = ()

    @property
    def exceptions(self) -> ExceptionNames:
        """INVT's own meanings of 04H-09H (06H: a data frame error, not "busy")."""
        return INVT_EXCEPTIONS

    @property
    def max_fault_code(self) -> int:
        return max(self.faults.entries, default=0)

    @property
    def parameter_table(self) -> ParameterTable:
        """The series' Pxx.yy parameters (ranges, decimals, marks, words): `parameter_tables`."""
        return series_table(self.key)

    @property
    def parameters(self) -> tuple[Parameter, ...]:
        return self.parameter_table.rows

    @property
    def parameter_groups(self) -> dict[str, tuple[Parameter, ...]]:
        """ "P00" → its parameters, in order: how `params backup` files them."""
        return parameter_groups(self.parameters)

    def with_overrides(
        self,
        *,
        identification: tuple[int, ...] | None = None,
        faults: Mapping[int, str] | None = None,
        ready_bit_set_means_ready: bool | None = None,
    ) -> InvtProfile:
        """This profile with a site's corrections of unconfirmed facts (from the config)."""
        profile = self
        if identification:
            profile = replace(profile, identification=identification, identification_confirmed=True)
        if faults:
            profile = replace(profile, faults=profile.faults.with_overrides(faults))
        if ready_bit_set_means_ready is not None:
            profile = replace(
                profile,
                ready_bit_set_means_ready=ready_bit_set_means_ready,
                ready_bit_source="drives[].ready_bit_set_means_ready in the config",
                unconfirmed=tuple(u for u in profile.unconfirmed if u != UNCONFIRMED_READY_BIT),
            )
        return profile

    @property
    def fault_register(self) -> int | None:
        """The register the current fault code is read from (2102H on every INVT model; 5000H
        mirrors it on the GD350 family and the GD300-LIFT)."""
        return self.fault_registers[0] if self.fault_registers else None

    def decimals(self, register_name: str, default: int) -> int:
        return self.decimals_overrides.get(register_name, default)

    # -- the `DriveProfile` protocol ----------------------------------------------------------
    # The decoders and the command codecs are modules of their own, below this one: they read
    # a series through small protocols of their own (`words.Series`), never this class.

    @property
    def manufacturer(self) -> str:
        return "INVT"

    @property
    def split_by_default(self) -> bool:
        return True  # every INVT chapter: "the max. continuous reading is 16 words"

    def telemetry(self, registers: Mapping[int, int]) -> Telemetry:
        return decode_telemetry(self, registers)

    @property
    def telemetry_keys(self) -> frozenset[str]:
        return TELEMETRY_KEYS

    def point(self, address: int) -> Point | None:
        return self.resolve(format_register(address))

    def resolve(self, text: str) -> Point:
        return resolve(text)

    def point_write(self, name: str, value: object) -> RegisterWrite:
        raise ValueError(no_typed_points(self.display_name))

    def current_fault(self, registers: Mapping[int, int]) -> int | None:
        return current_fault(self, registers)

    def fault_fields(self, code: int) -> Telemetry:
        return fault_fields(self, code)

    @property
    def commands(self) -> tuple[str, ...]:
        return tuple(CONTROL_COMMANDS)

    def command_name(self, name: str) -> str:
        return control_command(name).name.lower()

    def setpoint_word(self, frequency_hz: float) -> int:
        return setpoint_word(frequency_hz)

    def control_writes(
        self, command: str | None, setpoint: int | None
    ) -> tuple[RegisterWrite, ...]:
        return (control_write(None if command is None else control_command(command), setpoint),)

    def ram_only_address(self, address: int, spelled: str) -> int:
        return ram_only_address(address, spelled, self)

    @property
    def max_frequency_parameter(self) -> Parameter | None:
        return parameter(MAX_FREQUENCY)


UNCONFIRMED_READY_BIT: Final = "state word 2 ready-bit polarity"
"""How `unconfirmed` names a series whose 2101H bit 0 no manual page we found states."""

# 2101H bit 0, where a series' communication chapter states it (quoted from the page):
GD300_READY_BIT: Final = (
    'Goodrive300 Series VFD, communication protocol, page 219: "Bit0: =0: not ready for '
    'operation =1: ready for operation" (easymanua.ls/invt/gd300-004g-4/manual?p=224)'
)
GD350_READY_BIT: Final = (
    "Goodrive350 IP55 High-ingress Protection Series VFD, communication protocol, page -282-: "
    '"Bit0: =0: Not ready to run =1: Ready to run" (easymanua.ls/invt/gd350-045g-055p-45-as-b/'
    "manual?p=291); the team's design notes read the same in the GD350 chapter"
)
GD30_READY_BIT: Final = (
    'Goodrive30 Series VFD, chapter 7 communication protocol, page -135-: "Bit0: =0: Not ready '
    'to run =1: Ready to run" (easymanua.ls/invt/goodrive30-vfd-series/manual?p=141)'
)
GD35_READY_BIT: Final = (
    'Goodrive35 inverters, communication protocol, page 279: "Bit0: =0:ready for operation '
    '=1:not ready for operation" (easymanua.ls/invt/goodrive-35-series/manual?p=280)'
)
GD300L_READY_BIT: Final = (
    "Goodrive300-LIFT series inverter, 10.4.5 data address definition, page -126-: "
    '"Bit0: =0: ready for operation =1: not ready for operation" '
    "(manualshive.com/en/manual/invt/gd300l-series/2085743?page=130)"
)
GD10_READY_BIT: Final = (
    'Goodrive10 inverters, 7.4 communication protocol, page 87: "Bit0: =0:bus voltage is not '
    'established =1:bus voltage is established" (manualshive.com/en/manual/universal-motors/'
    "goodrive-10/1058543?page=88): the same polarity, in other words"
)


class _Named(TypedDict):
    key: str
    display_name: str
    identification: tuple[int, ...]
    identification_confirmed: bool


def _named(key: str) -> _Named:
    """A series' key, name and 2103H codes, as `invt_codes.SERIES_CODES` gives them."""
    series = SERIES_CODES[key]
    return _Named(
        key=key,
        display_name=series.display_name,
        identification=series.codes,
        identification_confirmed=series.confirmed,
    )


def _own_fault_list(key: str, name: str) -> FaultTable:
    """The fault codes a series' own parameter table lists for P07.27 (its manual's words):
    fault codes decode from the model's own list, never another series'."""
    row = series_table(key).named("P07.27")
    if row is None or not row.confirmed:
        raise TableError(f"{key}: its parameter table has no P07.27 of its own manual")
    return GOODRIVE_FAULTS.only(row.choices, name)


def _gd350_family(key: str, ready_bit_source: str = "") -> InvtProfile:
    """GD350-UL and GD350A: their own chapters' 2101H rows were not found; the GD350's
    polarity is assumed and marked unconfirmed."""
    return InvtProfile(
        **_named(key),
        fault_registers=(FAULT_CODE, FAULT_CODE_MIRROR),
        manufacturer_group=99,
        ready_bit_source=ready_bit_source,
        virtual_input_bits=10,
        faults=GD350_FAULTS,
        unconfirmed=() if ready_bit_source else (UNCONFIRMED_READY_BIT,),
    )


_PROFILES: Final = (
    InvtProfile(**_named("gd20"), unconfirmed=(UNCONFIRMED_READY_BIT,)),
    InvtProfile(
        **_named("gd200a"),
        unconfirmed=(UNCONFIRMED_READY_BIT,),
        faults=_own_fault_list("gd200a", "Goodrive200A (its manual's P07.27)"),
    ),
    InvtProfile(
        **_named("gd300"),
        manufacturer_group=29,
        ready_bit_source=GD300_READY_BIT,
    ),
    _gd350_family("gd350", GD350_READY_BIT),
    _gd350_family("gd350ul"),
    _gd350_family("gd350a"),
    InvtProfile(
        **_named("gd10"),
        manufacturer_group=29,
        ready_bit_source=GD10_READY_BIT,
    ),
    InvtProfile(
        **_named("gd35"),
        manufacturer_group=29,
        ready_bit_set_means_ready=False,
        ready_bit_source=GD35_READY_BIT,
    ),
    InvtProfile(**_named("gd100"), unconfirmed=(UNCONFIRMED_READY_BIT,)),
    # Goodrive30 ("Goodrive30 Series VFD", chapter 7 Communication protocol, manual page -135-,
    # easymanua.ls/invt/goodrive30-vfd-series/manual?p=141): 2101H bit 0 "=1: Ready to run", bits
    # 2-1 motor 1 or 2 ("=10: Reserved =11: Reserved"); 2009H's own row lists motors 1-4, so a
    # write of 3 or 4 is not refused; virtual inputs 0x000-0x1FF, outputs 0x00-0x0F. Its 2103H
    # code and fault list: not found (see the module docstring).
    InvtProfile(
        **_named("gd30"),
        aliases=("goodrive30",),
        manufacturer_group=29,
        faults=UNCONFIRMED_GOODRIVE_FAULTS,
        motors=2,
        ready_bit_source=GD30_READY_BIT,
        unconfirmed=("identification code (placeholder 01F0H)", "fault table"),
    ),
    # IPE300 ("IPE300 series engineering VFD", 9.4 Communication protocol, manual pages
    # -281- to -291-, easymanua.ls/invt/ipe300-series/manual?p=292..302): 03H/10H at most 16
    # words, 08H loop-back, exceptions 01H-09H, 2000H 0001H forward run, 2001H set-point,
    # P00.01 = 2 and P00.06 = 8 for remote control, fault 35 = STo: the common map. Its register
    # table pages (2100H-2103H) and fault chapter were not reachable: code and fault list unknown.
    InvtProfile(
        **_named("ipe300"),
        aliases=("ipe", "ipe300series"),
        faults=UNCONFIRMED_GOODRIVE_FAULTS,
        unconfirmed=(
            "identification code (placeholder 01F1H)",
            "fault table",
            UNCONFIRMED_READY_BIT,
            "manufacturer parameter group",
        ),
    ),
    # Goodrive300-LIFT ("Goodrive300-LIFT series inverter", 10.4.5 Data address definition,
    # manual pages -126-/-127-, manualshive.com/en/manual/invt/gd300l-series/2085743?page=130
    # and ?page=131): 2103H "GD300-----0x010a", mirrored at 3016H; fault code at 2102H and again
    # at 5000H; 2101H bit 0 "=0: ready for operation"; running values 3000H-3015H as the common
    # map (3007H output torque -250.0..250.0 %, 300AH/300BH 000-1FF). Its fault list: not found.
    InvtProfile(
        **_named("gd300l"),
        aliases=("gd300lift", "goodrive300lift"),
        fault_registers=(FAULT_CODE, FAULT_CODE_MIRROR),
        manufacturer_group=29,
        ready_bit_set_means_ready=False,
        ready_bit_source=GD300L_READY_BIT,
        faults=UNCONFIRMED_GOODRIVE_FAULTS,
        unconfirmed=("fault table", "manufacturer parameter group"),
    ),
)
INVT_PROFILES: Final[Mapping[str, InvtProfile]] = MappingProxyType(
    {profile.key: profile for profile in _PROFILES}
)
"""Every INVT series by key (`gateway.profile.models` names them all, with the other makers')."""


def profiles_for_identification(code: int) -> tuple[InvtProfile, ...]:
    """Every series that answers `code` at 2103H (010AH: GD300 and GD300-LIFT)."""
    return tuple(INVT_PROFILES[key] for key in series_keys_for_identification(code))
