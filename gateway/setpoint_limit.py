"""Why a drive refused a set-point, in words that name its limit: the one owner of that message,
for the console's toast and MQTT's answer alike.

An INVT drive refuses a set-point above its maximum frequency (P00.03) with a bare 04H
("the written value is invalid"). The gateway knows that maximum: `gateway.poller.max_frequency`
reads it. After a refusal the maximum is read again, now (someone may have changed it since the
gateway started); when that read fails, the value the poller read at start stands in. Only when
the refused set-point is indeed above the maximum does the message name it: a 04H for any other
reason keeps the drive's own words.
"""

from __future__ import annotations

from collections.abc import Mapping

from gateway.poller.max_frequency import read_max_frequencies
from gateway.profile.exception_codes import OPERATION_FAILURE
from gateway.routing import Router
from gateway.settings import DriveSettings

READ_BUDGET_S = 1.0
"""How long the refusal's answer may wait for the drive's maximum (one read on its bus)."""


def above_maximum(frequency_hz: float, parameter: str, maximum_hz: float) -> str:
    """ "60.00 Hz is above P00.03 = 50.00 Hz, the drive's maximum"."""
    return f"{frequency_hz:.2f} Hz is above {parameter} = {maximum_hz:.2f} Hz, the drive's maximum"


async def setpoint_refusal(
    router: Router,
    drive: DriveSettings,
    frequency_hz: float,
    code: int,
    read_at_start: Mapping[str, float],
) -> str:
    """What a drive's exception `code` to a set-point of `frequency_hz` means: "04H operation
    failure: 60.00 Hz is above P00.03 = 50.00 Hz, the drive's maximum" when the drive's maximum
    is known and below it, the profile's description of `code` otherwise."""
    exceptions = drive.profile.exceptions
    known = drive.profile.max_frequency_parameter
    if code != OPERATION_FAILURE or known is None:
        return exceptions.describe(code)
    now = await read_max_frequencies(router, [drive], READ_BUDGET_S)
    maximum = now.get(drive.name, read_at_start.get(drive.name))
    if maximum is None or frequency_hz <= maximum:
        return exceptions.describe(code)
    name = exceptions.name(code).replace("_", " ")
    return f"{code:02X}H {name}: {above_maximum(frequency_hz, known.name, maximum)}"
