"""What a profile of a device that is not a drive answers to the drive's part of the protocol
(`gateway.profile.protocol.DriveProfile`): no fault word, no commands, no set-point, no RAM-only
writes, no function parameters. The generic device and the typed-points devices share it."""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, ClassVar

from gateway.profile.exception_codes import STANDARD_EXCEPTIONS, ExceptionNames
from gateway.profile.overrides import FaultOverrides
from gateway.profile.parameter_tables import ParameterTable

if TYPE_CHECKING:
    from gateway.profile.protocol import RegisterWrite
    from gateway.profile.telemetry import Telemetry


class NotADrive(FaultOverrides):
    """Mixed into a profile dataclass that has a `display_name` and a (empty) `faults` table."""

    key: str
    display_name: str
    no_commands_hint: ClassVar[str] = ""
    """Said after "takes no drive commands" (what to do instead, e.g. ": write its points")."""

    @property
    def exceptions(self) -> ExceptionNames:
        """A device that is not a drive speaks the Modbus standard's exceptions."""
        return STANDARD_EXCEPTIONS

    @property
    def parameter_table(self) -> ParameterTable:
        """No function parameters: an empty table."""
        return ParameterTable(self.key, ())

    def current_fault(self, registers: Mapping[int, int]) -> int | None:
        return None

    def fault_fields(self, code: int) -> Telemetry:
        return {}

    def command_name(self, name: str) -> str:
        raise ValueError(f"a {self.display_name} takes no drive commands{self.no_commands_hint}")

    def setpoint_word(self, frequency_hz: float) -> int:
        raise ValueError(f"a {self.display_name} has no frequency set-point")

    def control_writes(
        self, command: str | None, setpoint: int | None
    ) -> tuple[RegisterWrite, ...]:
        raise ValueError(f"a {self.display_name} takes no drive commands{self.no_commands_hint}")

    def ram_only_address(self, address: int, spelled: str) -> int:
        raise ValueError(f"{self.display_name} has no RAM-only writes")
