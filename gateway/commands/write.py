"""`invt-gateway write --port DEV --address 1 P00.11=10.0 frequency_setpoint=25.00`.

Values are given as shown (10.0 s, 25.00 Hz) and scaled for the wire from the profile; the
control word also takes command names (control_word=run_forward, =stop, =fault_reset). Each is
one 06H write, confirmed by the drive's echo. `--ram` writes parameters to their RAM-only
address (no EEPROM wear; lost at power-off). `--via tcp://HOST:PORT` goes through a gateway.
"""

from __future__ import annotations

import argparse
import sys

from gateway.cli import EXIT_FAILURE, EXIT_OK, EXIT_USAGE
from gateway.commands.line_options import add_target_arguments


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "write",
        help="write registers or parameters of one drive, in engineering units",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_target_arguments(parser)
    parser.add_argument(
        "--ram", action="store_true", help="write parameters to RAM only (8xxxH), sparing EEPROM"
    )
    parser.add_argument(
        "assignments", nargs="+", metavar="NAME=VALUE", help="P00.11=10.0, 2001H=25.00, ..."
    )
    parser.set_defaults(handler=handle)


def handle(args: argparse.Namespace) -> int:
    from gateway.errors import FieldError
    from gateway.profile import Point, resolve
    from gateway.tools.access import write_point
    from gateway.tools.open import open_master

    writes: list[tuple[Point, int]] = []
    try:
        for assignment in args.assignments:
            name, equals, value = assignment.partition("=")
            if not equals or not value.strip():
                raise ValueError(f"{assignment!r}: expected NAME=VALUE, e.g. P00.11=10.0")
            point = resolve(name)
            writes.append((point, point.encode(value)))
    except ValueError as exc:
        print(f"invt-gateway write: {exc}", file=sys.stderr)
        return EXIT_USAGE
    try:
        master = open_master(args)
    except FieldError as exc:
        print(f"invt-gateway write: {exc}", file=sys.stderr)
        return EXIT_FAILURE
    try:
        for point, raw in writes:
            # Stop at the first failure: later writes may depend on earlier ones.
            print(write_point(master, args.address, point, raw, ram=args.ram), flush=True)
    except FieldError as exc:
        print(f"invt-gateway write: {exc}", file=sys.stderr)
        return EXIT_FAILURE
    finally:
        master.close()
    return EXIT_OK
