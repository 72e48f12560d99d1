"""`invt-gateway read --port DEV --address 1 P00.11 2100H output_frequency`: read and explain.

Each name is one register (Pxx.yy, 2100H, a profile name), printed scaled with its unit and
decoded where it is a code. `--via tcp://HOST:PORT` asks a running gateway instead of the line.

State word 2 (2101H) and fault codes read differently by series, and a parameter is scaled by
the series' table (profile/data/; the common table knows 25 codes): the series is `--model`, or
what the drive's 2103H names (read once, only for those); where 2103H can't tell (010AH: GD300
or GD300-LIFT, whose bit 0 polarities differ), 2101H bit 0 is shown undecided.
"""

from __future__ import annotations

import argparse
import sys

from gateway.commands.line_options import add_target_arguments
from gateway.exit_codes import EXIT_FAILURE, EXIT_OK, EXIT_USAGE


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "read",
        help="read registers or parameters of one drive, scaled and explained",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_target_arguments(parser)
    parser.add_argument(
        "--model", help="the drive's series (gd350, gd300l...), when 2103H can't tell (010AH)"
    )
    parser.add_argument(
        "points", nargs="+", metavar="NAME", help="P00.11, 2100H, 0x3000, frequency_setpoint, ..."
    )
    parser.set_defaults(handler=handle)


def handle(args: argparse.Namespace) -> int:
    from gateway.errors import FieldError
    from gateway.profile import get_profile, resolve
    from gateway.profile.points import beyond_common_table, for_series
    from gateway.tools.access import read_point, series_of
    from gateway.tools.open import open_master

    try:
        profile = None if args.model is None else get_profile(args.model)
        # Without --model, INVT's names: the series, if it matters, is asked of the drive.
        points = [
            resolve(name) if profile is None else profile.resolve(name) for name in args.points
        ]
    except ValueError as exc:
        print(f"invt-gateway read: {exc}", file=sys.stderr)
        return EXIT_USAGE
    try:
        master = open_master(args)
    except FieldError as exc:
        print(f"invt-gateway read: {exc}", file=sys.stderr)
        return EXIT_FAILURE
    failed = False
    try:
        if profile is None and any(
            point.depends_on_series or beyond_common_table(point) for point in points
        ):
            profile = series_of(master, args.address)
        points = [for_series(point, profile) for point in points]
        for point in points:
            try:
                print(read_point(master, args.address, point, profile).line(), flush=True)
            except FieldError as exc:
                print(f"invt-gateway read: {exc}", file=sys.stderr)
                failed = True
    finally:
        master.close()
    return EXIT_FAILURE if failed else EXIT_OK
