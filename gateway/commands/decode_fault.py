"""`invt-gateway decode-fault 35` → `STo: maladjustment`: INVT fault codes in words."""

from __future__ import annotations

import argparse
import sys

from gateway.cli import EXIT_OK, EXIT_USAGE


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "decode-fault",
        help="explain INVT fault codes (2102H, 5000H, P07.27-P07.32)",
        description=__doc__,
    )
    parser.add_argument(
        "codes", nargs="+", metavar="CODE", help="decimal as the keypad shows it, or 23H / 0x23"
    )
    parser.set_defaults(handler=handle)


def handle(args: argparse.Namespace) -> int:
    from gateway.profile import describe_fault

    try:
        codes = [fault_code(text) for text in args.codes]
    except ValueError as exc:
        print(f"invt-gateway decode-fault: {exc}", file=sys.stderr)
        return EXIT_USAGE
    for code in codes:
        print(describe_fault(code) if len(codes) == 1 else f"{code}: {describe_fault(code)}")
    return EXIT_OK


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
