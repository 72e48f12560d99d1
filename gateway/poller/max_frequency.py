"""Each drive's maximum output frequency (its profile's `max_frequency_parameter`: P00.03 on an
INVT drive), read once at start.

Home Assistant's set-point entity needs a maximum; the drive's own is the true one (it
refuses a set-point above it). Read through the router at poll priority, every drive at once,
within a budget: a drive that doesn't answer in time keeps its profile's factory value, and the
gateway's start is never held up for longer than the budget.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Iterable
from typing import Final

from gateway.errors import GatewayError
from gateway.modbus.functions import is_exception
from gateway.profile import Parameter
from gateway.routing import Router
from gateway.settings import DriveSettings

log = logging.getLogger(__name__)

READ_BUDGET_S: Final = 1.0


async def read_max_frequencies(
    router: Router, drives: Iterable[DriveSettings], budget_s: float = READ_BUDGET_S
) -> dict[str, float]:
    """Drive name → maximum frequency in Hz, for the drives whose profile names the parameter
    and that answered within `budget_s`."""
    tasks = {
        drive.name: asyncio.create_task(
            _read(router, drive, known), name=f"{known.name.lower()}:{drive.name}"
        )
        for drive in drives
        if (known := drive.profile.max_frequency_parameter) is not None
    }
    if not tasks:
        return {}
    done, pending = await asyncio.wait(tasks.values(), timeout=budget_s)
    for task in pending:
        task.cancel()
    if pending:
        await asyncio.wait(pending)
    found = {}
    for name, task in tasks.items():
        if task in done and not task.cancelled() and task.exception() is None:
            value = task.result()
            if value is not None:
                found[name] = value
    return found


async def _read(router: Router, drive: DriveSettings, known: Parameter) -> float | None:
    try:
        route = router.route_for_drive(drive.name)
        reply = await router.poll(route, known.address, 1)
    except GatewayError as exc:
        log.debug("drive %s: %s not read at start: %s", drive.name, known.name, exc)
        return None
    if reply is None or is_exception(reply) or len(reply) != 4:
        return None
    return int.from_bytes(reply[2:4], "big") / float(10**known.decimals)
