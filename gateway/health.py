"""The service's health as a service manager or a load balancer asks for it.

- live: the process answers at all. The report is made on the event loop, so a loop that is
  stuck doesn't answer and the caller's timeout says "not live".
- ready: start-up is done (buses opened or retrying, Modbus-TCP listening) and no shutdown has
  begun. An offline drive or a missing adapter doesn't make the gateway unready: it still
  answers every request (0x0B for those drives) and restarting it would fix nothing. The
  report lists them, as "degraded", for a person or an alert to act on. So does a store that
  can't keep events on disk (a full disk, a file it can't open): SCADA is served, but the events
  are in memory only, where a restart loses them; `store.reason` names storage.path and why.
- redundancy (`redundancy:`): the role (standby, listening, active), the peer, the last change
  and why, another master's frames heard. A standby's buses are closed on purpose: that is no
  degradation (its drives are the active gateway's to report); a port it can't open to listen
  is (`redundancy.deaf` names its bus: it can't hear that line, so can't take it over safely).
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Mapping
from enum import StrEnum
from typing import Any

from gateway.bus import Bus, BusState
from gateway.store.status import StoreStatus


class Phase(StrEnum):
    STARTING = "starting"
    READY = "ready"
    STOPPING = "stopping"


def health_report(
    phase: Phase,
    buses: Mapping[str, Bus],
    drives: Iterable[tuple[str, str, int]],
    tcp_clients: int,
    started_at: float,
    store: StoreStatus | None = None,
    redundancy: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """The JSON body of /health; `drives` are (drive, bus, address)."""
    per_bus: dict[str, dict[str, Any]] = {
        name: {
            "state": str(bus.state),
            "port": bus.settings.line.port,
            "queue_depth": bus.queue_depth,
            "drives_online": [],
            "drives_offline": [],
        }
        for name, bus in buses.items()
    }
    for drive, bus_name, address in drives:
        bus = buses[bus_name]
        key = "drives_offline" if bus.health.is_offline(address) else "drives_online"
        per_bus[bus_name][key].append(drive)
    standby = redundancy is not None and redundancy.get("role") != "active"
    deaf = standby and bool(redundancy and redundancy.get("deaf"))
    deaf = deaf or (redundancy is not None and redundancy.get("fit") is False)
    degraded = deaf or (
        not standby
        and any(
            bus.state is not BusState.OPEN or report["drives_offline"]
            for bus, report in zip(buses.values(), per_bus.values(), strict=True)
        )
    )
    degraded = degraded or (store is not None and not store.ok)
    ready = phase is Phase.READY
    status = ("degraded" if degraded else "ok") if ready else str(phase)
    report: dict[str, Any] = {
        "status": status,
        "live": True,
        "ready": ready,
        "uptime_s": round(time.monotonic() - started_at, 3),
        "tcp_clients": tcp_clients,
        "buses": per_bus,
    }
    if store is not None:
        report["store"] = store.as_json()
    if redundancy is not None:
        report["redundancy"] = dict(redundancy)
    return report
