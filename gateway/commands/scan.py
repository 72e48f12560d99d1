"""`invt-gateway scan --port DEV --baud 19200 [--parity E]`: which drives are on this line?

Probes each address with an 08H loop-back (a silent address costs one short timeout), then reads
2100H-2103H of those that answer, and prints a table: address, model (from the identification
code), state, fault, and where the drive takes its run commands from (P00.01).
"""

from __future__ import annotations

import argparse
import sys
import time
from typing import TYPE_CHECKING, TextIO

from gateway.commands.line_options import add_serial_arguments
from gateway.exit_codes import EXIT_FAILURE, EXIT_OK, EXIT_USAGE
from gateway.progress import duration_text
from gateway.tools import SCAN_TIMEOUT_MS

if TYPE_CHECKING:
    from rich.console import Console

    from gateway.tools.masters import Master
    from gateway.tools.scan import FoundDrive, ScanResult

FIRST_ADDRESS = 1
LAST_ADDRESS = 247
PLAIN_EVERY_S = 2.0
"""Without a terminal, how often a line says how far the scan got."""


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "scan",
        help="find the drives on a line: address, model, state, fault",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_serial_arguments(
        parser, timeout_ms=SCAN_TIMEOUT_MS, timeout_help=f"default {SCAN_TIMEOUT_MS:g}"
    )
    parser.add_argument(
        "--addresses",
        type=address_ranges,
        default=list(range(FIRST_ADDRESS, LAST_ADDRESS + 1)),
        metavar="LIST",
        help="addresses to probe, e.g. 1-32 or 1,5,10-12 (default 1-247)",
    )
    parser.set_defaults(handler=handle)


def address_ranges(text: str) -> list[int]:
    """ "1-3,7" → [1, 2, 3, 7]; every address within 1..247."""
    addresses: list[int] = []
    try:
        for part in text.split(","):
            first, _, last = part.strip().partition("-")
            addresses.extend(range(int(first), int(last or first) + 1))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected e.g. 1-32 or 1,5,10-12") from None
    if not addresses or not all(FIRST_ADDRESS <= a <= LAST_ADDRESS for a in addresses):
        raise argparse.ArgumentTypeError(f"{text!r}: addresses are {FIRST_ADDRESS}..{LAST_ADDRESS}")
    return sorted(set(addresses))


def handle(args: argparse.Namespace) -> int:
    from rich.console import Console

    from gateway.errors import FieldError
    from gateway.tools.open import open_serial, serial_options
    from gateway.tools.report import line_notes, no_drive_found, result_table
    from gateway.tools.scan import scan

    if args.timeout_ms <= 0:
        print("invt-gateway scan: --timeout-ms must be positive", file=sys.stderr)
        return EXIT_USAGE
    # A late reply must not be taken for the next address's answer; a short drain is enough
    # because a scan never retries, and the loop-back is tiny.
    options = serial_options(args, drain_ms=0.0)
    try:
        master = open_serial(options)
    except FieldError as exc:
        print(f"invt-gateway scan: {exc}", file=sys.stderr)
        return EXIT_FAILURE
    progress_console = Console(stderr=True)
    what = f"scanning {options.describe()}"
    try:
        if progress_console.is_terminal:
            result = scan_with_bar(master, args.addresses, what, progress_console)
        else:
            result = scan(master, args.addresses, PlainProgress(what, len(args.addresses)))
        notes = line_notes(master.line)
    finally:
        master.close()
    if not result.found:
        print(f"invt-gateway scan: {no_drive_found(options, result)}", file=sys.stderr)
        for note in notes:
            print(f"line: {note}", file=sys.stderr)
        return EXIT_FAILURE
    console = Console(soft_wrap=True)
    console.print(result_table(options, result))
    for note in notes:
        console.print(f"line: {note}", markup=False)
    return EXIT_OK


def scan_with_bar(master: Master, addresses: list[int], what: str, console: Console) -> ScanResult:
    """On a terminal: a bar redrawn in place, with the drives found and the time left."""
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeRemainingColumn,
    )

    from gateway.tools.scan import scan

    with Progress(
        TextColumn("[progress.description]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("{task.fields[found]} found"),
        TimeRemainingColumn(),
        console=console,
        transient=True,
    ) as progress:
        task = progress.add_task(what, total=len(addresses), found=0)
        count = 0

        def advance(address: int, found: FoundDrive | None) -> None:
            nonlocal count
            count += found is not None
            progress.update(task, advance=1, found=count)

        return scan(master, addresses, advance)


class PlainProgress:
    """Where stderr is no terminal (a script, a log, `ssh host invt-gateway scan | ...`): a line
    when the scan starts, one per drive found, and one every `PLAIN_EVERY_S` with how far it
    got, so a scan of 247 addresses (about 20 s at 19200 baud) is never silent."""

    def __init__(self, what: str, total: int, out: TextIO | None = None) -> None:
        self.total = total
        self.out = out or sys.stderr
        self.done = 0
        self.found = 0
        self.started = time.monotonic()
        self.shown = self.started
        self._print(f"{what}: {total} address{'es' if total != 1 else ''}")

    def __call__(self, address: int, found: FoundDrive | None) -> None:
        self.done += 1
        if found is not None:
            self.found += 1
            self._print(f"a drive answers at address {address}")
        now = time.monotonic()
        if now - self.shown >= PLAIN_EVERY_S and self.done < self.total:
            self.shown = now
            self._print(
                f"{self.done} of {self.total} addresses probed, {self.found} found, "
                f"{duration_text(now - self.started)} elapsed"
            )

    def _print(self, text: str) -> None:
        print(f"scan: {text}", file=self.out, flush=True)
