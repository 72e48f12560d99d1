"""`invt-gateway check-config --config FILE`: validate a configuration and print its routing table.

Validates the file as `run` would (every key, its type and range, the cross-checks: unique unit
ids, no two buses on one port, drives on defined buses; and what `run` needs of this machine:
its listeners on ports of their own, its TLS files there and what they claim to be, its bind
addresses this machine's), then prints which unit id reaches which
drive on which line, and how much of each line its polls take (a line its polls alone would
fill is a warning, and so is one they take more than 70 % of: too little left for SCADA). Exit
0 when valid, 3 when not (each key and its reason are printed). A serial port that isn't there on
this machine is a warning, not an error: the file may be checked on another machine than the
gateway box, but on the box `run` would keep trying to open it.

With `--peer FILE` (the other box's file of a redundant pair, copied here: `scp gw-b:/etc/
invt-gateway/config.yaml peer.yaml`), it says what differs between the two files after the
rest: what the two boxes must share (the buses, the drives and their poll groups, the MQTT
broker and base topic, the gateway id...) and, apart, what each box may set its own way (its
`redundancy.box`, `peer`, `hold_off_ms`, `role` and `fault_file`, its addresses, its adapters'
device paths, its store's path, its logging). Exit 1 when they differ in what they must share.
"""

from __future__ import annotations

import argparse
import sys

from gateway.commands.run import DEFAULT_CONFIG, load_or_report
from gateway.config import GatewayConfig
from gateway.config.peer import differences
from gateway.config.startup import startup_problems
from gateway.errors import ConfigError
from gateway.exit_codes import EXIT_CONFIG, EXIT_FAILURE, EXIT_OK
from gateway.poller.budget import line_budget
from gateway.settings import runtime_settings
from gateway.settings.checks import missing_ports


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "check-config",
        help="validate a configuration file and print the routing table",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--config", "-c", default=DEFAULT_CONFIG, help="YAML file")
    parser.add_argument(
        "--peer", metavar="FILE", help="the other redundant box's file: say what differs"
    )
    parser.set_defaults(handler=handle)


def handle(args: argparse.Namespace) -> int:
    config = load_or_report(args.config)
    if config is None:
        return EXIT_CONFIG
    problems = startup_problems(config)
    if problems:
        # Said as a file that doesn't validate is: `run` could not start on it either.
        print(f"invt-gateway: {ConfigError(problems, args.config)}", file=sys.stderr)
        return EXIT_CONFIG
    print(f"{args.config}: valid")
    for warning in missing_ports(config):
        print(f"warning: {warning}", file=sys.stderr)
    print(routing_table(config))
    print()
    budget, overloaded = line_budget(runtime_settings(config))
    print(budget)
    for warning in overloaded:
        print(f"warning: {warning}", file=sys.stderr)
    if config.modbus_tcp.access:
        print()
        print(access_table(config))
    return EXIT_OK if args.peer is None else compare_peer(config, args.peer)


def compare_peer(config: GatewayConfig, path: str) -> int:
    """What differs from the other box's file; EXIT_FAILURE when it is what both must share."""
    peer = load_or_report(path)
    if peer is None:
        return EXIT_CONFIG
    found = differences(config, peer)
    shared = [d for d in found if not d.own]
    print()
    if shared:
        print(f"peer {path}: differs in what both boxes must share:")
        for difference in shared:
            print(f"  {difference.describe()}")
    else:
        print(f"peer {path}: alike in everything both boxes must share")
    own = [d for d in found if d.own]
    if own:
        print("each box's own (may differ):")
        for difference in own:
            print(f"  {difference.describe()}")
    return EXIT_FAILURE if shared else EXIT_OK


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
