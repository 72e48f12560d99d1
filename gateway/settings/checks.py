"""The warnings a configuration gets wherever it is checked (`check-config`, the console's
editor): a serial port missing on this machine, a line its polls would fill. A warning, not a
problem: the file may be checked on another machine than the gateway box, and a busy line still
runs. (What keeps a file from starting is `gateway.config.startup`.)
"""

from __future__ import annotations

import os

from gateway.config import GatewayConfig


def missing_ports(config: GatewayConfig) -> list[str]:
    """A sentence for each bus whose serial device doesn't exist on this machine (a pyserial
    URL, socket:// or rfc2217://, is a network address: not checked)."""
    found = []
    for index, bus in enumerate(config.buses):
        if "://" in bus.port or os.path.exists(bus.port):
            continue
        found.append(
            f"buses[{index}].port: {bus.port} does not exist on this machine (is the adapter "
            "plugged in? /dev/serial/by-id/ lists the adapters by a name that survives a "
            "replug); `run` would keep trying to open it"
        )
    return found


def line_budget(config: GatewayConfig) -> tuple[str, list[str]]:
    """Each line's poll load (of the drives `run` would poll), and a warning for each line the
    polls would fill."""
    from gateway.poller.budget import POLL_BUDGET, line_plans
    from gateway.settings import runtime_settings

    settings = runtime_settings(config)
    plans = line_plans(settings.buses, (d for d in settings.drives if settings.polled(d)))
    lines = ["Poll load (wire time of every planned read; each device's answer delay on top):"]
    overloaded = []
    for index, bus in enumerate(config.buses):
        plan = plans[bus.name]
        load = plan.total
        lines.append(
            f"  {bus.name}: {len(plan.drives)} polled, {load.requests_per_s:.1f} requests/s, "
            f"{load.busy_fraction:.1%} of the line"
        )
        lines += [
            f"    {name}: {drive.requests_per_s:.1f} requests/s, {drive.busy_fraction:.1%}"
            for name, drive in plan.drives.items()
        ]
        if load.busy_fraction >= 1.0:
            overloaded.append(
                f"buses[{index}] ({bus.name}): its polls alone need {load.busy_fraction:.0%} of "
                "the line: polls will fall behind; lengthen intervals (interval_ms) or raise "
                "the baud rate"
            )
        elif plan.over_budget:
            overloaded.append(
                f"buses[{index}] ({bus.name}): its polls take {load.busy_fraction:.0%} of the "
                f"line, more than {POLL_BUDGET:.0%}: little is left for SCADA's requests, "
                "commands and retries; lengthen intervals (interval_ms) or raise the baud rate"
            )
    return "\n".join(lines), overloaded
