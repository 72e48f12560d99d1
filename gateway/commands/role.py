"""`invt-gateway role active|standby|status [--config FILE]`: a redundant gateway's role.

For Keepalived's notify script (`config/invt-gateway-notify.sh`: MASTER asks `active`, BACKUP
and FAULT ask `standby`) and for people. It asks the gateway that runs with the same `--config`
file through the control socket (`gateway.control`) and returns at once: `active` is taken once
the line has been heard silent (`role status` says when it was), `standby` once the buses have
stopped.

    ok: active: listening: takes the line once it has been silent 1.5 s
    ok: standby: standby: listening only, never transmitting
    {"asked": "standby", "role": "standby", "line_silent_s": 0.012, ...}     (role status)

Exit codes: 0 asked (or the status printed), 1 refused (no `redundancy:` in the gateway's
configuration, an unknown role) or no gateway reached, or (`status`, printed too, with a line
`unfit: ...`) no port of the box's lines has opened for `PORTLESS_S` (1 s): its adapter
unplugged, so it can't be the line's master; or, on a box with no `fault_file`, it has heard
another master for `LATCH_S` while asked active (a cut between the boxes: it must not hold the
virtual address; with a fault file that file tells Keepalived, and `status` exits 0).
"""

from __future__ import annotations

import argparse
import sys

from gateway.commands.config_path import DEFAULT_CONFIG
from gateway.control import ROLE, ask
from gateway.errors import ControlUnavailable
from gateway.exit_codes import EXIT_FAILURE, EXIT_OK

TIMEOUT_S = 10.0


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "role",
        help="ask a redundant gateway to be active or standby, or for its role (Keepalived)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("role", choices=("active", "standby", "status"))
    parser.add_argument(
        "--config", "-c", default=DEFAULT_CONFIG, help="the YAML file the gateway runs with"
    )
    parser.add_argument("--timeout", type=float, default=TIMEOUT_S, metavar="S")
    parser.set_defaults(handler=handle)


def handle(args: argparse.Namespace) -> int:
    try:
        answer = ask(args.config, f"{ROLE} {args.role}", args.timeout)
    except ControlUnavailable as exc:
        print(f"invt-gateway: role: {exc}", file=sys.stderr)
        return EXIT_FAILURE
    if answer and not any(line.startswith("refused:") for line in answer):
        print("\n".join(answer))
        # `status` of a box that can't be the line's master (no port open): Keepalived's
        # track script fails on it, and the virtual address moves.
        unfit = any(line.startswith("unfit:") for line in answer)
        return EXIT_FAILURE if unfit else EXIT_OK
    print("\n".join(answer) or "no answer: the gateway hung up", file=sys.stderr)
    return EXIT_FAILURE
