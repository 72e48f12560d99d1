"""The `invt-gateway` command: a thin dispatcher over one module per sub-command.

Each module in `gateway.commands` has `register(subparsers)`, which adds its parser and sets
`handler` to a function taking the parsed arguments and returning the exit code.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Callable, Sequence

from gateway import __version__

# Sub-command modules, in the order `--help` lists them.
COMMAND_MODULES = (
    "gateway.commands.run",
    "gateway.commands.check_config",
    "gateway.commands.demo",
    "gateway.commands.simulate",
    "gateway.commands.bench",
    "gateway.commands.stress",
    "gateway.commands.scan",
    "gateway.commands.read",
    "gateway.commands.write",
    "gateway.commands.decode_fault",
    "gateway.commands.params",
    "gateway.commands.healthcheck",
    "gateway.commands.hash_password",
    "gateway.commands.monitor",
)

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_USAGE = 2
EXIT_CONFIG = 3
"""A configuration that does not validate: its own code, so the service manager shows why."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="invt-gateway",
        description="Modbus-TCP and MQTT gateway for INVT drives on RS-485 (Modbus-RTU).",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(subparsers)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    handler: Callable[[argparse.Namespace], int] = args.handler
    try:
        return handler(args)
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
