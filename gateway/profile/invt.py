"""Drive profiles: what differs between INVT models, as data.

Facts marked **unconfirmed** in the INVT notes are fields here rather than code, so a site can
correct them without a code change:
- `ready_bit_set_means_ready`: the polarity of 2101H bit 0 "differs by model";
- `decimals_overrides`: the bus-voltage scale (3002H) on GD200A/GD20;
- `ram_writes_via_10h`: whether 10H accepts RAM-only (8xxxH) addresses.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Final

STATE_WORD_1: Final = 0x2100
FAULT_CODE: Final = 0x2102
FAULT_CODE_GD350: Final = 0x5000
IDENTIFICATION: Final = 0x2103
RUNNING_FREQUENCY: Final = 0x3000

INVT_MAX_WORDS: Final = 16
"""03H and 10H: "the max. continuous reading is 16 words", contiguous addresses."""
MODBUS_MAX_WORDS: Final = 125
"""The Modbus limit for 03H: a generic device never needs a request split."""

IDENTIFICATION_CODES: Final[dict[int, str]] = {
    0x0106: "GD20",
    0x0107: "GD200A",
    0x010C: "GD200A",  # the manuals disagree between 0107H and 010CH: both are taken as GD200A
    0x0108: "GD35",
    0x0109: "GD35-H1",
    0x010A: "GD300",
    0x010B: "GD100",
    0x010D: "GD10",
    0x01A0: "GD350",
    0x01A1: "GD350-UL",
    0x01A2: "GD350A",
}


def model_from_identification(code: int) -> str | None:
    """ "GD350" for 01A0H; None for a code no manual lists (GD30 and IPE300 are unknown)."""
    return IDENTIFICATION_CODES.get(code)


def describe_identification(code: int) -> str:
    return model_from_identification(code) or f"unknown model ({code:04X}H)"


@dataclass(frozen=True)
class PollGroup:
    """A block the poller reads from each drive: `count` words from `start` every `interval_s`."""

    name: str
    start: int
    count: int
    interval_s: float


STATE_POLL: Final = PollGroup("state", STATE_WORD_1, 3, 0.5)
"""2100H-2102H: state word 1, state word 2, fault code."""
RUNNING_POLL: Final = PollGroup("running", RUNNING_FREQUENCY, 12, 2.0)
"""3000H-300BH: frequency, voltages, current, speed, power, torque, PID, terminals."""


@dataclass(frozen=True)
class DriveProfile:
    key: str
    display_name: str
    identification: tuple[int, ...] = ()
    """Codes the drive answers at 2103H; the first is the one a simulated drive answers."""
    max_words: int = INVT_MAX_WORDS
    fault_registers: tuple[int, ...] = (FAULT_CODE,)
    poll_groups: tuple[PollGroup, ...] = (STATE_POLL, RUNNING_POLL)
    ram_writes_supported: bool = True
    ram_writes_via_10h: bool = True  # unconfirmed
    manufacturer_group: int | None = None
    """A parameter group that can be neither read nor written (P99 on GD350, P29 on GD10...)."""
    ready_bit_set_means_ready: bool = True  # unconfirmed
    decimals_overrides: Mapping[str, int] = field(default_factory=lambda: MappingProxyType({}))
    """Register name → decimals where this model differs from the register map."""
    virtual_input_bits: int = 9
    max_fault_code: int = 36

    @property
    def is_invt(self) -> bool:
        return bool(self.identification)

    @property
    def fault_register(self) -> int | None:
        """The register the current fault code is read from (2102H on every INVT model)."""
        return self.fault_registers[0] if self.fault_registers else None

    def decimals(self, register_name: str, default: int) -> int:
        return self.decimals_overrides.get(register_name, default)


def _gd350_family(key: str, name: str, code: int) -> DriveProfile:
    return DriveProfile(
        key,
        name,
        identification=(code,),
        fault_registers=(FAULT_CODE, FAULT_CODE_GD350),
        manufacturer_group=99,
        ready_bit_set_means_ready=False,  # unconfirmed: GD350 lists bit 0 = 0 as "ready"
        virtual_input_bits=10,
        max_fault_code=69,
    )


_PROFILES: Final = (
    DriveProfile("gd20", "GD20", identification=(0x0106,)),
    DriveProfile("gd200a", "GD200A", identification=(0x0107, 0x010C)),
    DriveProfile("gd300", "GD300", identification=(0x010A,), manufacturer_group=29),
    _gd350_family("gd350", "GD350", 0x01A0),
    _gd350_family("gd350ul", "GD350-UL", 0x01A1),
    _gd350_family("gd350a", "GD350A", 0x01A2),
    DriveProfile("gd10", "GD10", identification=(0x010D,), manufacturer_group=29),
    DriveProfile("gd35", "GD35", identification=(0x0108,), manufacturer_group=29),
    DriveProfile("gd100", "GD100", identification=(0x010B,)),
    DriveProfile(
        "generic",
        "generic Modbus device",
        max_words=MODBUS_MAX_WORDS,
        fault_registers=(),
        poll_groups=(),
        ram_writes_supported=False,
        ram_writes_via_10h=False,
    ),
)
PROFILES: Final[Mapping[str, DriveProfile]] = MappingProxyType(
    {profile.key: profile for profile in _PROFILES}
)


def get_profile(name: str) -> DriveProfile:
    """The profile called `name` ("gd350", case-insensitive); ValueError lists the valid ones."""
    key = name.strip().lower().replace("-", "").replace("_", "")
    try:
        return PROFILES[key]
    except KeyError:
        raise ValueError(
            f"unknown drive profile {name!r}: valid profiles are {', '.join(PROFILES)}"
        ) from None
