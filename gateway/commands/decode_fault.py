"""`invt-gateway decode-fault 35` → `STo: maladjustment`: INVT fault codes in words.

`--model gd30` decodes with that series' own fault table: a code it doesn't list is
"unknown fault N" (never another series' name), and the exit code is 1. Without `--model` the
widest table (GD350 family, 0-69) is used.
"""

from __future__ import annotations

import argparse
import sys

from gateway.cli import EXIT_FAILURE, EXIT_OK, EXIT_USAGE


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "decode-fault",
        help="explain INVT fault codes (2102H, 5000H, P07.27-P07.32)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--model",
        metavar="MODEL",
        help="the drive's series (gd20, gd30, ipe300, gd300l, gd350a...): decode with its table",
    )
    parser.add_argument(
        "codes", nargs="+", metavar="CODE", help="decimal as the keypad shows it, or 23H / 0x23"
    )
    parser.set_defaults(handler=handle)


def handle(args: argparse.Namespace) -> int:
    from gateway.profile import get_profile, words

    try:
        codes = [fault_code(text) for text in args.codes]
        profile = None if args.model is None else get_profile(args.model)
    except ValueError as exc:
        print(f"invt-gateway decode-fault: {exc}", file=sys.stderr)
        return EXIT_USAGE
    table = words.fault_table(None) if profile is None else profile.faults
    for code in codes:
        text = table.describe(code)
        print(text if len(codes) == 1 else f"{code}: {text}")
    if args.model is not None and not table.confirmed:
        print(
            f"note: the {args.model} fault table is the {table.name}: "
            "no public manual of the series confirmed it",
            file=sys.stderr,
        )
    return EXIT_OK if all(table.knows(code) for code in codes) else EXIT_FAILURE


def fault_code(text: str) -> int:
    """ "35", "23H" or "0x23" → 35."""
    spelled = text.strip().lower()
    try:
        code = int(spelled[:-1], 16) if spelled.endswith("h") else int(spelled, 0)
    except ValueError:
        raise ValueError(f"{text!r} is not a fault code: write 35, 23H or 0x23") from None
    if not 0 <= code <= 0xFFFF:
        raise ValueError(f"{text!r} is not a fault code: it must fit in one register")
    return code
