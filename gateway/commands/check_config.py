"""`invt-gateway check-config --config FILE`: validate a configuration and print its routing table.

Validates the file as `run` would (every key, its type and range, the cross-checks: unique unit
ids, no two buses on one port, drives on defined buses), then prints which unit id reaches which
drive on which line, and how much of each line its polls take (a line its polls alone would
fill is a warning, and so is one they take more than 70 % of: too little left for SCADA). Exit
0 when valid, 3 when not (the key and the reason are printed). A serial port that isn't there on
this machine is a warning, not an error: the file may be checked on another machine than the
gateway box, but on the box `run` would keep trying to open it.
"""

from __future__ import annotations

import argparse
import os
import sys

from gateway.commands.run import DEFAULT_CONFIG, load_or_report
from gateway.config import GatewayConfig
from gateway.exit_codes import EXIT_CONFIG, EXIT_OK


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "check-config",
        help="validate a configuration file and print the routing table",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--config", "-c", default=DEFAULT_CONFIG, help="YAML file")
    parser.set_defaults(handler=handle)


def handle(args: argparse.Namespace) -> int:
    config = load_or_report(args.config)
    if config is None:
        return EXIT_CONFIG
    print(f"{args.config}: valid")
    for warning in missing_ports(config):
        print(f"warning: {warning}", file=sys.stderr)
    print(routing_table(config))
    print()
    budget, overloaded = line_budget(config)
    print(budget)
    for warning in overloaded:
        print(f"warning: {warning}", file=sys.stderr)
    if config.modbus_tcp.access:
        print()
        print(access_table(config))
    return EXIT_OK


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


def access_table(config: GatewayConfig) -> str:
    """The access rules as the gateway reads them: what each one matches, in order."""
    lines = ["Modbus-TCP access (first matching rule decides; no match: allowed):"]
    for index, rule in enumerate(config.modbus_tcp.access):
        units = "any unit id" if rule.unit_ids is None else "unit ids " + _listed(rule.unit_ids)
        functions = (
            "any function"
            if rule.functions is None
            else "functions " + ", ".join(f"{f:02X}H" for f in rule.functions)
        )
        registers = ""
        if rule.registers is not None:
            spans = [span for entry in rule.registers for span in entry.spans]
            registers = ", registers " + ", ".join(
                f"{a:04X}H" if a == b else f"{a:04X}H-{b:04X}H" for a, b in spans
            )
        verdict = "allow" if rule.allow else "refuse"
        name = rule.name or f"access[{index}]"
        lines.append(f"  {index + 1}. {verdict:6} {units}, {functions}{registers}  ({name})")
    return "\n".join(lines)


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


def _listed(values: tuple[int, ...]) -> str:
    return ", ".join(map(str, values))


def routing_table(config: GatewayConfig) -> str:
    buses = {bus.name: bus for bus in config.buses}
    header = ("unit id", "drive", "bus", "address", "model", "port", "serial", "timeout")
    rows = [header]
    for drive in sorted(config.drives, key=lambda d: d.effective_unit_id):
        bus = buses[drive.bus]
        timeout = bus.timeout_ms if drive.timeout_ms is None else drive.timeout_ms
        rows.append(
            (
                str(drive.effective_unit_id),
                drive.name,
                bus.name,
                str(drive.address),
                drive.model,
                bus.port,
                f"{bus.baudrate} {bus.bytesize}{bus.parity}{bus.stopbits}",
                f"{timeout:g} ms",
            )
        )
    widths = [max(len(row[i]) for row in rows) for i in range(len(header))]
    lines = [
        "  ".join(cell.ljust(w) for cell, w in zip(row, widths, strict=True)).rstrip()
        for row in rows
    ]
    if not config.drives:
        lines.append("(no drives configured)")
    return "\n".join(lines)
