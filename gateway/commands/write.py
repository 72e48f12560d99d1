"""`invt-gateway write --port DEV --address 1 P00.11=10.0 frequency_setpoint=25.00`.

Values are given as shown (10.0 s, 25.00 Hz) and scaled for the wire from the profile: a
parameter by the series' table (`--model`, or what the drive's 2103H names, read only when a
parameter is beyond the common table's 25 codes); the control word also takes command names
(control_word=run_forward, =stop, =fault_reset). Each is one 06H write, confirmed by the
drive's echo. `--ram` writes parameters to their RAM-only address (no EEPROM wear; lost at
power-off). `--via tcp://HOST:PORT` goes through a gateway.
"""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING

from gateway.commands.line_options import add_target_arguments
from gateway.exit_codes import EXIT_FAILURE, EXIT_OK, EXIT_USAGE

if TYPE_CHECKING:
    from gateway.profile import DriveProfile
    from gateway.profile.points import Point


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
        "--model", help="the drive's series (gd350, gd200a...), whose table scales parameters"
    )
    parser.add_argument(
        "assignments", nargs="+", metavar="NAME=VALUE", help="P00.11=10.0, 2001H=25.00, ..."
    )
    parser.set_defaults(handler=handle)


def handle(args: argparse.Namespace) -> int:
    from gateway.errors import FieldError
    from gateway.profile import get_profile, resolve
    from gateway.profile.points import beyond_common_table
    from gateway.tools.access import series_of, write_point
    from gateway.tools.open import open_master

    assignments: list[tuple[Point, str]] = []
    writes: list[tuple[Point, int]] | None = None
    try:
        profile = None if args.model is None else get_profile(args.model)
        for assignment in args.assignments:
            name, equals, value = assignment.partition("=")
            if not equals or not value.strip():
                raise ValueError(f"{assignment!r}: expected NAME=VALUE, e.g. P00.11=10.0")
            # Without --model, INVT's names: the series, if it matters, is asked of the drive.
            point = resolve(name) if profile is None else profile.resolve(name)
            assignments.append((point, value))
        if profile is not None or not any(beyond_common_table(p) for p, _ in assignments):
            writes = _encoded(assignments, profile)  # checked before the line is opened
    except ValueError as exc:
        print(f"invt-gateway write: {exc}", file=sys.stderr)
        return EXIT_USAGE
    try:
        master = open_master(args)
    except FieldError as exc:
        print(f"invt-gateway write: {exc}", file=sys.stderr)
        return EXIT_FAILURE
    try:
        if writes is None:  # a parameter only the drive's own series table scales
            try:
                writes = _encoded(assignments, series_of(master, args.address))
            except ValueError as exc:
                print(f"invt-gateway write: {exc}", file=sys.stderr)
                return EXIT_USAGE
        for point, raw in writes:
            # Stop at the first failure: later writes may depend on earlier ones.
            line = write_point(master, args.address, point, raw, ram=args.ram, profile=profile)
            print(line, flush=True)
    except FieldError as exc:
        print(f"invt-gateway write: {exc}", file=sys.stderr)
        return EXIT_FAILURE
    finally:
        master.close()
    return EXIT_OK


def _encoded(
    assignments: list[tuple[Point, str]], profile: DriveProfile | None
) -> list[tuple[Point, int]]:
    """Each value as the wire word, a parameter scaled by `profile`'s series table."""
    from gateway.profile.points import for_series

    points = [(for_series(point, profile), value) for point, value in assignments]
    return [(point, point.encode(value)) for point, value in points]
