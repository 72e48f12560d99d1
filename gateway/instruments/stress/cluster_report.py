"""`stress --cluster`'s table, its JSON document, and the verdict.

The run passes when every event id every gateway stored reached the dashboard (duplicates are
counted, not failed: QoS 1 is at least once, and dashboards de-duplicate by id), every drive's
retained state was read with its latest change through every live node within 5 s, no command
ran twice, and every gateway came back (said "online" through a live node) within
`RESUME_LIMIT_S` of each SIGKILL. When the dashboard's own session got that "online" is printed
too, not judged: NATS 2.9 may hold a persistent session's QoS 1 deliveries until a dead node is
back (every event still arrives: that is judged).
"""

from __future__ import annotations

from typing import Any

from gateway.instruments.stress.cluster import (
    CLUSTER_WAIT_S,
    RESUME_LIMIT_S,
    RETAINED_WITHIN_S,
    ClusterResult,
    RetainedRead,
)


def problems(result: ClusterResult) -> list[str]:
    found = []
    for delivery in result.deliveries:
        if delivery.missing:
            found.append(
                f"{delivery.gateway}: {len(delivery.missing)} stored events never reached the "
                f"dashboard (ids {list(delivery.missing[:10])})"
            )
        if delivery.stored == 0:
            found.append(f"{delivery.gateway}: no event stored")
    for read in result.retained:
        if read.seconds is None:
            found.append(
                f"retained states through {read.node} ({read.moment}) not all new within "
                f"{RETAINED_WITHIN_S:g} s: {len(read.stale)} stale, e.g. {list(read.stale[:3])}"
                + ("" if read.cluster_wait_s is not None else f"{_waited(read)}")
            )
    if result.commands.ran_twice:
        found.append(f"commands ran twice: {list(result.commands.ran_twice[:10])} Hz")
    if result.commands.ran == 0:
        found.append("no command ran")
    for resume in result.resumes:
        if resume.seconds is None:
            found.append(f"{resume.gateway} not back within {RESUME_LIMIT_S:g} s ({resume.cause})")
    expected_kills = min(3, result.settings.gateways)
    if result.node_kills < expected_kills or result.gateway_kills < 1:
        found.append(
            f"the run ended early: {result.node_kills} node kills, "
            f"{result.gateway_kills} gateway kills"
        )
    return found


def table(result: ClusterResult) -> str:
    settings = result.settings
    rows: list[tuple[str, str]] = []
    for delivery in result.deliveries:
        duplicates = delivery.received - delivery.distinct
        rows.append(
            (
                f"events of {delivery.gateway}",
                f"{delivery.stored} stored, {delivery.distinct} distinct ids at the dashboard, "
                f"{len(delivery.missing)} missing (must be 0), {duplicates} delivered twice",
            )
        )
    reads = result.retained
    timely = [r.seconds for r in reads if r.seconds is not None]
    rows.append(
        (
            "retained states",
            f"{len(reads)} reads of {settings.gateways * settings.drives} drives through each "
            f"live node, {len(timely)} new within {RETAINED_WITHIN_S:g} s (must be all); "
            f"slowest {max(timely, default=0.0):.2f} s",
        )
    )
    for read in reads:
        seconds = "NOT within 5 s" if read.seconds is None else f"{read.seconds:.2f} s"
        rows.append((f"  {read.moment}, via {read.node}", seconds + _waited(read)))
    commands = result.commands
    rows.append(
        (
            "set-points (commands)",
            f"{commands.sent} acknowledged by a node, {commands.unacknowledged} not; "
            f"{commands.ran} ran ({commands.unsent_ran} of them unacknowledged ones), "
            f"{len(commands.ran_twice)} ran twice (must be 0)",
        )
    )
    for resume in result.resumes:
        seconds = "NOT BACK" if resume.seconds is None else f"{resume.seconds:.2f} s"
        dashboard = (
            "not before its next kill or the end"
            if resume.dashboard_s is None
            else f"{resume.dashboard_s:.2f} s"
        )
        rows.append(
            (
                f"resume: {resume.gateway}",
                f"{seconds} after {resume.cause}, via {resume.server} "
                f"(at the dashboard's session: {dashboard})",
            )
        )
    rows.append(("dashboard", f"{result.dashboard_connections} connections, one session"))
    found = problems(result)
    rows.append(("verdict", "pass" if not found else "FAIL: " + "; ".join(found)))
    width = max(len(name) for name, _ in rows)
    title = (
        f"invt-gateway stress --cluster: {result.elapsed_s:.0f} s, {settings.gateways} gateways "
        f"of {settings.drives} drives on 3 NATS nodes; {result.node_kills} nodes and "
        f"{result.gateway_kills} gateway SIGKILLed"
    )
    return "\n".join([title, "", *(f"  {name.ljust(width)}  {value}" for name, value in rows)])


def document(result: ClusterResult) -> dict[str, Any]:
    settings = result.settings
    commands = result.commands
    return {
        "settings": {
            "duration_s": settings.duration_s,
            "gateways": settings.gateways,
            "drives": settings.drives,
            "command_interval_s": settings.command_interval_s,
        },
        "elapsed_s": round(result.elapsed_s, 3),
        "node_kills": result.node_kills,
        "gateway_kills": result.gateway_kills,
        "events": [
            {
                "gateway": d.gateway,
                "stored": d.stored,
                "received": d.received,
                "distinct": d.distinct,
                "duplicates": d.received - d.distinct,
                "missing": list(d.missing),
            }
            for d in result.deliveries
        ],
        "retained": [
            {
                "moment": r.moment,
                "node": r.node,
                "seconds": r.seconds,
                "stale": list(r.stale),
                "cluster_wait_s": (
                    None if r.cluster_wait_s is None else round(r.cluster_wait_s, 3)
                ),
            }
            for r in result.retained
        ],
        "commands": {
            "sent": commands.sent,
            "unacknowledged": commands.unacknowledged,
            "ran": commands.ran,
            "unacknowledged_ran": commands.unsent_ran,
            "ran_twice": list(commands.ran_twice),
        },
        "resumes": [
            {
                "gateway": r.gateway,
                "cause": r.cause,
                "seconds": r.seconds,
                "dashboard_s": r.dashboard_s,
                "server": r.server,
            }
            for r in result.resumes
        ],
        "dashboard_connections": result.dashboard_connections,
        "problems": problems(result),
        "passed": not problems(result),
    }


def _waited(read: RetainedRead) -> str:
    if read.cluster_wait_s is None:
        return (
            f" (the nodes did not share retained messages within {CLUSTER_WAIT_S:g} s: NATS's, "
            "e.g. a node's consumer of them 'has NO quorum, stalled' in its log)"
        )
    return f" (nodes sharing retained messages after {read.cluster_wait_s:.2f} s)"
