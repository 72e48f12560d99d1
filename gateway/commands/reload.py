"""`invt-gateway reload [--config FILE]`: the running gateway reads its file again; the outcome.

For `ExecReload=` and for people: unlike `kill -HUP`, it says whether the new configuration was
applied, and exits non-zero when it was not, so `systemctl reload` fails with the reason in its
status. It finds the gateway that runs with the same `--config` file through the control socket
(`gateway.control`): under systemd, in a container (`docker exec`), or beside a plain `run`.

Exit codes: 0 applied (keys that need a restart are named, and kept at their running values),
3 refused (the file does not validate: each problem with its key path; or its MQTT settings
would put the gateway on a base topic another live gateway holds; nothing changed),
1 skipped (the gateway is starting or stopping) or no gateway reached.
"""

from __future__ import annotations

import argparse
import sys

from gateway.commands.run import DEFAULT_CONFIG
from gateway.control import RELOAD, ask
from gateway.errors import ControlUnavailable
from gateway.exit_codes import EXIT_CONFIG, EXIT_FAILURE, EXIT_OK

TIMEOUT_S = 60.0
"""Reopening buses and restarting the MQTT bridge take seconds; systemd's own limit for
`ExecReload=` (TimeoutStartSec=) ends it sooner if it must."""


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "reload",
        help="have the running gateway apply its edited configuration; exit 0 only if applied",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--config", "-c", default=DEFAULT_CONFIG, help="the YAML file the gateway runs with"
    )
    parser.add_argument("--timeout", type=float, default=TIMEOUT_S, metavar="S")
    parser.set_defaults(handler=handle)


def handle(args: argparse.Namespace) -> int:
    try:
        answer = ask(args.config, RELOAD, args.timeout)
    except ControlUnavailable as exc:
        print(f"invt-gateway: reload: {exc}", file=sys.stderr)
        return EXIT_FAILURE
    if answer and all(line.startswith("applied:") for line in answer):
        print("\n".join(answer))
        return EXIT_OK
    print("\n".join(answer) or "no answer: the gateway hung up", file=sys.stderr)
    refused = answer and all(line.startswith("refused:") for line in answer)
    return EXIT_CONFIG if refused else EXIT_FAILURE
