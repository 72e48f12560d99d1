"""A Modbus device the gateway only carries (`model: generic`): no maker's knowledge at all.

Requests pass through unsplit up to Modbus's own limit, nothing is polled unless the config asks,
polled words are telemetry under their addresses (`register_0005h`), and nothing is a command.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Final

from gateway.profile.addressing import format_register, parse_register
from gateway.profile.faults import FaultTable
from gateway.profile.not_a_drive import NotADrive
from gateway.profile.parameters import Parameter
from gateway.profile.point_types import TypedPoint, no_typed_points
from gateway.profile.points import Point
from gateway.profile.protocol import PollGroup, RegisterWrite
from gateway.profile.telemetry import Telemetry

NO_FAULTS: Final = FaultTable("no fault table", {})
MODBUS_MAX_WORDS: Final = 125
"""The Modbus limit for 03H: a generic device never needs a request split."""


@dataclass(frozen=True)
class GenericProfile(NotADrive):
    key: str = "generic"
    display_name: str = "generic Modbus device"
    manufacturer: str = ""
    aliases: tuple[str, ...] = ()
    identification: tuple[int, ...] = ()
    unconfirmed: tuple[str, ...] = ()
    max_words: int = MODBUS_MAX_WORDS
    split_by_default: bool = False
    poll_groups: tuple[PollGroup, ...] = ()
    ram_writes_supported: bool = False
    faults: FaultTable = NO_FAULTS
    commands: tuple[str, ...] = ()
    parameters: tuple[Parameter, ...] = ()
    max_frequency_hz: float = 0.0
    max_frequency_parameter: Parameter | None = None
    telemetry_keys: frozenset[str] = frozenset()
    typed_points: tuple[TypedPoint, ...] = ()

    def telemetry(self, registers: Mapping[int, int]) -> Telemetry:
        """Nothing to decode: each word under its address."""
        return {
            f"register_{format_register(address).lower()}": word
            for address, word in sorted(registers.items())
        }

    def point(self, address: int) -> Point | None:
        return None

    def resolve(self, text: str) -> Point:
        address = parse_register(text)
        return Point(format_register(address), address, "not in the profile: shown raw")

    def point_write(self, name: str, value: object) -> RegisterWrite:
        raise ValueError(no_typed_points(self.display_name))


GENERIC: Final = GenericProfile()
