"""The `invt-gateway` command: a thin dispatcher over one module per sub-command.

Each module in `gateway.commands` has `register(subparsers)`, which adds its parser and sets
`handler` to a function taking the parsed arguments and returning the exit code (one of
`gateway.exit_codes`, which the commands import; none imports this module back).
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from collections.abc import Callable, Sequence

from gateway.exit_codes import EXIT_BROKEN_PIPE, EXIT_INTERRUPTED
from gateway.version import describe_version

# Sub-commands and their modules, in the order `--help` lists them. The service and the field
# tools a technician uses on real hardware, then the instruments (`gateway.instruments`), which
# an installation may leave out (the Docker image does).
COMMANDS = {
    "run": "gateway.commands.run",
    "check-config": "gateway.commands.check_config",
    "reload": "gateway.commands.reload",
    "role": "gateway.commands.role",
    "demo": "gateway.instruments.commands.demo",
    "simulate": "gateway.instruments.commands.simulate",
    "bench": "gateway.instruments.commands.bench",
    "stress": "gateway.instruments.commands.stress",
    "scan": "gateway.commands.scan",
    "read": "gateway.commands.read",
    "write": "gateway.commands.write",
    "decode-fault": "gateway.commands.decode_fault",
    "params": "gateway.commands.params",
    "healthcheck": "gateway.commands.healthcheck",
    "hash-password": "gateway.commands.hash_password",
    "monitor": "gateway.commands.monitor",
}
INSTRUMENTS = "gateway.instruments"


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The parser for every sub-command, or for `only` that one: the CLI loads the module of
    the command it runs and no other (`run` loads the service and nothing of the instruments)."""
    parser = argparse.ArgumentParser(
        prog="invt-gateway",
        description="Modbus-TCP and MQTT gateway for INVT drives on RS-485 (Modbus-RTU).",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {describe_version()}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, module_name in COMMANDS.items():
        if only is not None and name != only:
            continue
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            if exc.name is not None and exc.name.startswith(INSTRUMENTS):
                continue  # this installation carries no instruments (the Docker image)
            raise
        module.register(subparsers)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    arguments = list(sys.argv[1:] if argv is None else argv)
    command = next((word for word in arguments if not word.startswith("-")), None)
    parser = build_parser(command if command in COMMANDS else None)
    args = parser.parse_args(arguments)
    handler: Callable[[argparse.Namespace], int] = args.handler
    try:
        return handler(args)
    except KeyboardInterrupt:
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        # `| head` has read what it wanted: quiet, as a shell tool ends. Python's own flush of
        # stdout at exit would hit the closed pipe again, so stdout goes to /dev/null first.
        quiet = os.open(os.devnull, os.O_WRONLY)
        os.dup2(quiet, sys.stdout.fileno())
        return EXIT_BROKEN_PIPE


if __name__ == "__main__":
    sys.exit(main())
