"""`invt-gateway params backup|diff|restore FILE`: a drive's parameter set in a YAML file.

    invt-gateway params backup pump1.yaml --port /dev/ttyUSB0 --address 1
    invt-gateway params diff pump1.yaml --port /dev/ttyUSB0 --address 2
    invt-gateway params restore pump1.yaml --port /dev/ttyUSB0 --address 2 [--apply] [--ram]
    invt-gateway params diff --from-address 1 --port /dev/ttyUSB0 --address 2

`backup` saves every writable parameter of the drive's series table (profile/data/) by group,
with units, the manual's words for each value and the model (from 2103H, or --model); codes of
an unconfirmed table the drive does not have are listed, not fatal. `diff` lists what differs
(exit 1 when anything does). `restore` shows that list and writes only what differs, and only
with --apply (a dry run otherwise), each write read back afterwards; --ram writes RAM only
(8xxxH, lost at power-off). With --from-address N instead of FILE, `diff` and `restore` take
drive N on the same line for the file: a clone without a file. Read-only and
factory-set parameters are skipped with the reason; a running drive is refused (stop it
first: nothing is written); the first exception the drive answers stops it, naming the
parameter. `--via tcp://HOST:PORT` goes through a running
gateway (address = unit id).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING

from gateway.commands.line_options import add_target_arguments
from gateway.exit_codes import EXIT_FAILURE, EXIT_OK, EXIT_USAGE

if TYPE_CHECKING:
    from gateway.tools.masters import Master
    from gateway.tools.params import Difference, ParameterSet, Skipped


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "params",
        help="back up, compare and restore a drive's parameters (YAML)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    actions = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    backup = actions.add_parser("backup", help="save the drive's writable parameters to FILE")
    backup.add_argument("--model", help="the drive's series when 2103H can't tell (010AH)")
    diff = actions.add_parser("diff", help="compare FILE with the drive (exit 1 if they differ)")
    restore = actions.add_parser("restore", help="write what differs from FILE (with --apply)")
    restore.add_argument("--apply", action="store_true", help="write; without it, a dry run")
    restore.add_argument("--ram", action="store_true", help="write RAM only (8xxxH), no EEPROM")
    backup.add_argument("file", metavar="FILE", type=Path)
    add_target_arguments(backup)
    for action in (diff, restore):
        action.add_argument("file", metavar="FILE", type=Path, nargs="?")
        action.add_argument(
            "--from-address",
            type=int,
            metavar="N",
            help="compare with (or restore from) the drive at address N instead of FILE",
        )
        action.add_argument("--model", help="drive N's series when its 2103H can't tell")
        add_target_arguments(action)
    parser.set_defaults(handler=handle)


def handle(args: argparse.Namespace) -> int:
    from gateway.errors import FieldError
    from gateway.tools.open import open_master

    from_drive = args.action != "backup" and args.from_address is not None
    try:
        if args.action != "backup" and (args.file is None) == (args.from_address is None):
            raise ValueError("give either FILE or --from-address N")
        wanted = None if args.action == "backup" or from_drive else load(args.file)
    except ValueError as exc:
        print(f"invt-gateway params: {exc}", file=sys.stderr)
        return EXIT_USAGE
    try:
        master = open_master(args)
    except FieldError as exc:
        print(f"invt-gateway params: {exc}", file=sys.stderr)
        return EXIT_FAILURE
    try:
        if args.action == "backup":
            return backup(master, args)
        if wanted is None:
            wanted = read_drive(master, args)
        return compare(master, args, wanted)
    except FieldError as exc:
        print(f"invt-gateway params: {exc}", file=sys.stderr)
        return EXIT_FAILURE
    finally:
        master.close()


def load(path: Path) -> ParameterSet:
    from gateway.tools.params import from_yaml

    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ValueError(f"cannot read {path}: {exc.strerror or exc}") from None
    return from_yaml(text, str(path))


def backup(master: Master, args: argparse.Namespace) -> int:
    from gateway.tools.params import (
        ParameterSet,
        profile_of,
        read_parameters,
        saved_parameters,
        to_yaml,
    )

    try:
        profile, code = profile_of(master, args.address, args.model)
    except ValueError as exc:  # an unknown --model
        print(f"invt-gateway params: {exc}", file=sys.stderr)
        return EXIT_USAGE
    specs = saved_parameters(profile)
    absent: list[str] = []
    started = time.monotonic()
    with progress(f"reading {profile.display_name} at {args.address}", len(specs)) as step:
        values = read_parameters(
            master, args.address, specs, step, max_words=profile.max_words, absent=absent
        )
    took = time.monotonic() - started
    text = to_yaml(ParameterSet(profile, values), code, args.address, absent=absent)
    try:
        args.file.write_text(text, encoding="utf-8")
    except OSError as exc:
        print(f"invt-gateway params: cannot write {args.file}: {exc.strerror}", file=sys.stderr)
        return EXIT_FAILURE
    groups = sorted({spec.group for spec in specs if spec.name in values})
    print(
        f"{args.file}: {len(values)} parameters of {profile.display_name} at address "
        f"{args.address} ({', '.join(groups)}) in {took:.1f} s"
    )
    unconfirmed = profile.parameter_table.unconfirmed_groups
    if unconfirmed:
        print(
            f"unconfirmed for {profile.display_name} (another series' table): "
            f"{', '.join(unconfirmed)}",
            file=sys.stderr,
        )
    if absent:
        print(f"not on this drive (exception 02H): {', '.join(absent)}", file=sys.stderr)
    return EXIT_OK


def read_drive(master: Master, args: argparse.Namespace) -> ParameterSet:
    """Drive N's parameter set, as `backup` would save it: what a clone copies."""
    from gateway.errors import FieldError
    from gateway.tools.params import ParameterSet, profile_of, read_parameters, saved_parameters

    try:
        profile, _ = profile_of(master, args.from_address, args.model)
    except ValueError as exc:  # an unknown --model
        raise FieldError(str(exc)) from None
    specs = saved_parameters(profile)
    absent: list[str] = []
    with progress(f"reading {profile.display_name} at {args.from_address}", len(specs)) as step:
        values = read_parameters(
            master, args.from_address, specs, step, max_words=profile.max_words, absent=absent
        )
    return ParameterSet(profile, values)


def _source(args: argparse.Namespace) -> str:
    return str(args.file) if args.file is not None else f"the drive at {args.from_address}"


def compare(master: Master, args: argparse.Namespace, wanted: ParameterSet) -> int:
    from gateway.errors import FieldError
    from gateway.tools.params import (
        differences,
        identify,
        plan,
        read_parameters,
        refuse_if_running,
        running_state,
    )

    profile = wanted.profile
    code = identify(master, args.address)
    if code not in profile.identification:
        from gateway.profile import model_from_identification

        series = model_from_identification(code) or "unknown series"
        raise FieldError(
            f"the drive at address {args.address} answers 2103H = {code:04X}H ({series}); "
            f"{_source(args)} is of a {profile.display_name}: not compared"
        )
    specs = wanted.specs()
    with progress(f"reading {profile.display_name} at {args.address}", len(specs)) as step:
        actual = read_parameters(master, args.address, specs, step)
    changes = differences(wanted, actual)
    for change in changes:
        print(change.line())
    if args.action == "diff":
        print(f"{len(changes)} difference(s) in {len(specs)} parameters", file=sys.stderr)
        return EXIT_OK if not changes else EXIT_FAILURE
    writes, skipped = plan(changes, actual, profile.parameter_table)
    for skip in skipped:
        print(f"skipped {skip.difference.spec.name}: {skip.reason}")
    if not args.apply:
        print(f"dry run: {len(writes)} parameter(s) to write; --apply writes them")
        if writes and (state := running_state(master, args.address)) is not None:
            print(f"the drive runs (2100H = {state}): --apply refuses until it is stopped")
        return EXIT_OK
    if writes:
        refuse_if_running(master, args.address)
    return write_all(master, args, writes, wanted, skipped)


def write_all(
    master: Master,
    args: argparse.Namespace,
    writes: list[Difference],
    wanted: ParameterSet,
    skipped: list[Skipped],
) -> int:
    from gateway.errors import FieldError
    from gateway.tools.params import check_written, show, write_parameter

    done = 0
    held_otherwise = 0
    started = time.monotonic()
    with progress(f"writing address {args.address}", len(writes)) as step:
        for change in writes:
            try:
                write_parameter(master, args.address, change.spec, change.file, args.ram)
                # 8xxxH is write-only: a read gives the EEPROM's value, not the RAM's.
                held = (
                    None
                    if args.ram
                    else check_written(master, args.address, change.spec, change.file)
                )
            except FieldError as exc:
                exc.message += f" ({done} of {len(writes)} written before it; stopped here)"
                raise
            done += 1
            step(change.spec.name)
            print(f"{change.spec.name} <- {show(change.spec, change.file)}", flush=True)
            if held is not None and held != change.file:
                held_otherwise += 1
                print(f"read back {change.spec.name}: the drive holds {show(change.spec, held)}")
    took = time.monotonic() - started
    # Verified: each read back at once (what is shown above where the drive holds another).
    where = " to RAM only" if args.ram else " and verified"
    print(f"{done} parameter(s) written{where} in {took:.1f} s")
    if args.ram:
        return EXIT_OK
    checked = verify(master, args, wanted, {skip.difference.spec.name for skip in skipped})
    return EXIT_FAILURE if held_otherwise else checked


def verify(
    master: Master, args: argparse.Namespace, wanted: ParameterSet, skipped: set[str]
) -> int:
    """The file's parameters read back after writing: what the drive holds that differs is
    reported (a write may re-initialise other parameters, the drive may round a value)."""
    from gateway.tools.params import Difference, read_parameters

    specs = [spec for spec in wanted.specs() if spec.name not in skipped]
    with progress(f"reading back address {args.address}", len(specs)) as step:
        now = read_parameters(master, args.address, specs, step, max_words=16)
    wrong = [
        Difference(spec, now[spec.name], wanted.values[spec.name])
        for spec in specs
        if now[spec.name] != wanted.values[spec.name]
    ]
    for change in wrong:
        print(f"read back {change.line()}")
    if wrong:
        print(f"{len(wrong)} parameter(s) differ from the file after writing", file=sys.stderr)
        return EXIT_FAILURE
    return EXIT_OK


@contextmanager
def progress(description: str, total: int) -> Iterator[Callable[[str], None]]:
    """A progress bar on stderr while it is a terminal; nothing otherwise."""
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

    console = Console(stderr=True)
    if not console.is_terminal:
        yield lambda name: None
        return
    with Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("{task.fields[name]}"),
        console=console,
        transient=True,
    ) as bar:
        task = bar.add_task(description, total=total, name="")
        yield lambda name: bar.update(task, advance=1, name=name)
