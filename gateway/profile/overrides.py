"""A site's corrections of a profile's unconfirmed facts (`drives[].faults` and the like in the
config), for the profiles whose only such fact is their fault table: the ABB Drives profile,
the generic device and the typed-points devices. One `with_overrides` for all of them; the INVT
profile, which can also be told its identification code and its ready bit's polarity, has its
own (`invt.InvtProfile.with_overrides`)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from typing import TYPE_CHECKING, Any, Self

if TYPE_CHECKING:
    from gateway.profile.faults import FaultTable


class FaultOverrides:
    """Mixed into a frozen profile dataclass that has a `faults` table."""

    faults: FaultTable
    display_name: str

    def with_overrides(
        self,
        *,
        identification: tuple[int, ...] | None = None,
        faults: Mapping[int, str] | None = None,
        ready_bit_set_means_ready: bool | None = None,
    ) -> Self:
        """This profile with the site's fault names. An identification code or a ready bit's
        polarity are INVT facts these profiles don't have: ValueError naming the key."""
        if identification:
            raise ValueError(f"identification: {self.display_name} has no 2103H code to correct")
        if ready_bit_set_means_ready is not None:
            raise ValueError(
                f"ready_bit_set_means_ready: {self.display_name} has no INVT state word 2"
            )
        if not faults:
            return self
        dataclass_self: Any = self  # a dataclass: `replace` keeps every other field
        changed: Self = replace(dataclass_self, faults=self.faults.with_overrides(faults))
        return changed
