"""The warnings a configuration gets wherever it is checked (`check-config`, the console's
editor): a serial port missing on this machine (here), a line its polls would fill
(`gateway.poller.budget.line_budget`: the poll plan's own arithmetic). A warning, not a
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
