"""`invt-gateway check-config --config FILE`: validate and print the routing table."""

from __future__ import annotations

import argparse

from gateway.cli import EXIT_CONFIG, EXIT_OK
from gateway.commands.run import DEFAULT_CONFIG, load_or_report
from gateway.config import GatewayConfig


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "check-config", help="validate a configuration file and print the routing table"
    )
    parser.add_argument("--config", "-c", default=DEFAULT_CONFIG, help="YAML file")
    parser.set_defaults(handler=handle)


def handle(args: argparse.Namespace) -> int:
    config = load_or_report(args.config)
    if config is None:
        return EXIT_CONFIG
    print(f"{args.config}: valid")
    print(routing_table(config))
    return EXIT_OK


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
