"""`invt-gateway decode-fault 35` → `STo: maladjustment`: INVT fault codes in words.

`decode-fault OC1` (the keypad's short code, letter case aside) → `4: OC1: overcurrent while
accelerating`: what the code is, for a fault read off the drive's display.

`--model gd30` decodes with that series' own fault table: a code it doesn't list is
"unknown fault N" (never another series' name), and the exit code is 1. Without `--model` the
widest table (GD350 family, 0-69) is used.
"""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING

from gateway.exit_codes import EXIT_FAILURE, EXIT_OK, EXIT_USAGE

if TYPE_CHECKING:
    from gateway.profile.faults import FaultTable


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
        "codes",
        nargs="+",
        metavar="CODE",
        help="decimal as 2102H gives it, 23H / 0x23, or the keypad's short code (OC1, STo)",
    )
    parser.set_defaults(handler=handle)


def handle(args: argparse.Namespace) -> int:
    from gateway.profile import get_profile, words

    try:
        profile = None if args.model is None else get_profile(args.model)
        table = words.fault_table(None) if profile is None else profile.faults
        codes = [fault_code(text, table) for text in args.codes]
    except ValueError as exc:
        print(f"invt-gateway decode-fault: {exc}", file=sys.stderr)
        return EXIT_USAGE
    for given, code in zip(args.codes, codes, strict=True):
        text = table.describe(code)
        # Given by its keypad name, the number is the news; several: which is which.
        numbered = len(codes) > 1 or not given.strip()[:1].isdigit()
        print(f"{code}: {text}" if numbered else text)
    if args.model is not None and not table.confirmed:
        print(
            f"note: the {args.model} fault table is the {table.name}: "
            "no public manual of the series confirmed it",
            file=sys.stderr,
        )
    return EXIT_OK if all(table.knows(code) for code in codes) else EXIT_FAILURE


def fault_code(text: str, table: FaultTable) -> int:
    """ "35", "23H", "0x23" or the keypad's "STo" → 35."""
    spelled = text.strip().lower()
    try:
        code = int(spelled[:-1], 16) if spelled.endswith("h") else int(spelled, 0)
    except ValueError:
        by_keypad = table.code_of(text)
        if by_keypad is not None:
            return by_keypad
        raise ValueError(
            f"{text!r} is not a fault code: write 35, 23H, 0x23 or the keypad's short code "
            f"as the {table.name} table gives it (OC1, STo)"
        ) from None
    if not 0 <= code <= 0xFFFF:
        raise ValueError(f"{text!r} is not a fault code: it must fit in one register")
    return code
