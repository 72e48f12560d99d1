"""Probes: how a bus finds out that an offline drive is back.

A probe is a marker (`gateway.bus.late_replies`: an 08H echo, or a read the drive answered
before), never an optional function assumed; it has no waiter: the health tracker reads its
outcome.
"""

from __future__ import annotations

from gateway.bus.health import HealthTracker
from gateway.bus.queue import Priority, Transaction
from gateway.modbus.rtu import build_frame

PROBE_PDU = bytes.fromhex("0800000000")
"""What a probe asks for, as the traffic monitor shows it (on the wire: its marker)."""
PROBE_CLIENT = "probe"


def due_probes(
    health: HealthTracker, timeout_s: float, retries: int, now: float
) -> list[Transaction]:
    """One probe for each offline drive whose backoff is over (its next one postponed as it is
    made): a single attempt, or `retries` for a drive that went offline only because the port
    did."""
    probes = []
    for address in health.due_probes(now):
        health.postpone_probe(address, now)
        probes.append(
            Transaction(
                address=address,
                pdu=PROBE_PDU,
                priority=Priority.READ,
                client=PROBE_CLIENT,
                timeout_s=timeout_s,
                retries=retries if health.lost_with_line(address) else 0,
                probe=True,
                # A probe that comes due again while the last one still waits joins it: a long
                # queue after a reopen must not fill with copies, each costing its timeouts.
                coalescable=True,
                frame=build_frame(address, PROBE_PDU),
                queued_at=now,
            )
        )
    return probes
