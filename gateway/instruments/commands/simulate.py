"""`invt-gateway simulate`: a line of simulated INVT drives on a pty (or a serial device).

    invt-gateway simulate --pty --address 1 --address 2 [--link /tmp/ttyINVT]
    invt-gateway simulate --pty --address 1 --line-faults 0.05 --late-reply-ms 100
    invt-gateway simulate --pty --address 1 --burst-ms 40 --glitch FF --echo
    invt-gateway simulate --pty --drive 1=gd30 --drive 2=ipe300 --drive 3=acs580  (a mixed line)
    invt-gateway simulate --pty --lines 32 --address 1 --address 2  (32 lines, one process)
    invt-gateway simulate --pty --masters 2 --address 1  (one line, two gateways' adapters on it)

The first line on stdout is the device path to point the gateway at (with --lines N, the first
N lines: one path per line, each line with the same drives, its own pty and its own timing, all
served from one thread; with --masters N, one path per master on the one line: see
`gateway.instruments.simulator.shared_wire`). It serves until SIGTERM or SIGINT (exit 0). When
stdin is not a terminal, it takes control commands there, one per line (`fault 1 35`, `dead 2`,
`stats`, ...: see `gateway.instruments.simulator.control`; `line K ...` for the K-th of several
lines), each answered by one line on stdout.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import select
import signal
import sys
from collections.abc import Iterator, Sequence
from types import FrameType

from gateway.collector import settle_startup_objects
from gateway.exit_codes import EXIT_FAILURE, EXIT_OK, EXIT_USAGE
from gateway.instruments.simulator.abb_drive import ABB_MODELS
from gateway.instruments.simulator.control import run_line_command
from gateway.instruments.simulator.line import WAKE_EARLY_S, SimulatedLine
from gateway.instruments.simulator.line_faults import KINDS, late_range
from gateway.instruments.simulator.server import LineServer
from gateway.profile.invt import INVT_PROFILES
from gateway.profile.models import get_profile

PARITIES = ("N", "E", "O")
MAX_LINES = 64
MAX_MASTERS = 8
"""Masters one simulated line takes: a redundant pair, and a few more to misbehave."""
"""Lines one simulator process serves: beyond, one thread no longer keeps every reply on time."""
INVT_MODELS = tuple(INVT_PROFILES)
MODELS = (*INVT_MODELS, *sorted(ABB_MODELS))
"""What the simulator can play: every INVT series, and ABB drives on the ABB Drives profile."""


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "simulate",
        help="serve simulated INVT drives on a pty (for tests and demos without hardware)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_arguments(parser)
    parser.set_defaults(handler=handle)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument("--pty", action="store_true", help="create a pty and print its path")
    where.add_argument("--device", metavar="PATH", help="serve on an existing serial device")
    parser.add_argument("--link", metavar="PATH", help="a symlink to keep pointed at the port")
    parser.add_argument(
        "--lines",
        type=_lines,
        default=1,
        metavar="N",
        help="serve N lines alike from one thread, each on a pty of its own with its own wire "
        "timing; their paths are the first N lines on stdout, `line K COMMAND` controls the "
        "K-th (default 1; with --pty only, no --link)",
    )
    parser.add_argument(
        "--masters",
        type=_masters,
        default=1,
        metavar="N",
        help="N masters on the one line, each on a pty of its own (their paths are the first N "
        "lines on stdout): what one transmits reaches the drives and every other master, the "
        "drives' replies reach all, and two transmissions that overlap collide (the drives "
        "see a bad CRC); `stats` counts collisions and each master's frames (default 1; with "
        "--pty only, one line, no --link)",
    )
    parser.add_argument(
        "--address",
        type=_address,
        action="append",
        metavar="ADDR",
        help="a drive address 1..247 (repeat for several drives; default 1)",
    )
    parser.add_argument(
        "--model",
        default="gd350",
        choices=MODELS,
        help="the series of every drive not given with --drive (default gd350)",
    )
    parser.add_argument(
        "--drive",
        type=_drive,
        action="append",
        default=[],
        metavar="ADDR=MODEL",
        help="a drive of another series at ADDR, e.g. 3=gd300l or 4=acs580 (repeat: a mixed line)",
    )
    parser.add_argument("--baud", type=int, default=19200)
    parser.add_argument("--parity", default="E", type=str.upper, choices=PARITIES)
    parser.add_argument("--stopbits", type=int, default=1, choices=(1, 2))
    parser.add_argument(
        "--no-wire-time",
        dest="wire_time",
        action="store_false",
        help="answer as fast as the pty allows instead of at the baud rate's pace",
    )
    parser.add_argument("--response-delay-ms", type=float, default=5.0, metavar="MS")
    parser.add_argument(
        "--wake-early-us",
        type=_wake_early_us,
        default=WAKE_EARLY_S * 1e6,
        metavar="US",
        help=f"wake this long before a reply is due and spin out the rest, so replies leave on "
        f"time (default {WAKE_EARLY_S * 1e6:g}); several simulated lines on one machine should "
        f"share it, or their spinning takes the cores from what they measure",
    )
    parser.add_argument(
        "--fault",
        type=_pair,
        action="append",
        default=[],
        metavar="ADDR=CODE",
        help="start with this drive tripped",
    )
    parser.add_argument("--dead", type=_address, action="append", default=[], metavar="ADDR")
    parser.add_argument(
        "--slow",
        type=_slow,
        action="append",
        default=[],
        metavar="ADDR=MS[-MS]",
        help="this drive answers MS later than its response delay, or a delay drawn at random "
        "from MS-MS for each reply (a drive busy writing its EEPROM, a slow device server)",
    )
    parser.add_argument(
        "--fault-history",
        type=_history,
        action="append",
        default=[],
        metavar="ADDR=CODE,CODE,...",
        help="P07.27-P07.32 of a drive, newest first",
    )
    parser.add_argument(
        "--line-faults",
        type=_rate,
        default=0.0,
        metavar="RATE",
        help="spoil this share of the replies (0.05: 5 %%), as a noisy line would",
    )
    parser.add_argument(
        "--line-fault-kinds",
        type=_kinds,
        default=None,
        metavar="KIND,...",
        help=f"which ways to spoil them (default all: {','.join(sorted(KINDS))})",
    )
    parser.add_argument(
        "--line-fault-seed",
        type=int,
        default=None,
        metavar="N",
        help="the same seed spoils the same replies",
    )
    parser.add_argument(
        "--late-reply-ms",
        type=late_reply_ms,
        default=(500.0, 500.0),
        metavar="MS",
        help="how much later than due a 'late' reply comes: MS, or FROM-TO for a delay drawn "
        "at random from that range, as a drive busy writing its EEPROM answers (default 500)",
    )

    adapter = parser.add_argument_group(
        "the gateway's adapter", "what real RS-485 adapters do to the bytes the gateway receives"
    )
    adapter.add_argument(
        "--burst-ms",
        type=float,
        default=0.0,
        metavar="MS",
        help="hand replies over in bursts every MS ms, each reply cut in the middle, as a USB "
        "adapter's latency timer or a serial device server does (default 0: off)",
    )
    adapter.add_argument(
        "--glitch",
        type=_glitch,
        default=b"",
        metavar="HEX",
        help="one spurious byte (00 or FF) before every reply, as a transceiver switching "
        "direction puts on the line",
    )
    adapter.add_argument(
        "--relay-ms",
        type=_relay_ms,
        default=0.0,
        metavar="MS",
        help="a relay between the gateway's port and the drives' wire, delaying every byte MS "
        "ms each way, as a USB adapter's timer or a serial device server does (default 0: none)",
    )
    adapter.add_argument(
        "--echo",
        action="store_true",
        help="hand every request back as it arrives, as a 2-wire adapter without echo "
        "suppression does",
    )


def handle(args: argparse.Namespace) -> int:
    if args.lines > 1 and (args.device or args.link):
        print("invt-gateway simulate: --lines takes --pty and no --link", file=sys.stderr)
        return EXIT_USAGE
    if args.masters > 1 and (args.device or args.link or args.lines > 1):
        print(
            "invt-gateway simulate: --masters takes --pty, one line and no --link",
            file=sys.stderr,
        )
        return EXIT_USAGE
    # Signal handlers first: whoever reads the path may signal at once, and must get a clean
    # stop (the link removed, exit 0) rather than the default death.
    with _signal_pipe() as signalled:
        try:
            lines = [build_line(args) for _ in range(args.lines)]
            # As the gateway does: a full collection over the drives' registers stalled all
            # the lines 16 ms (32 lines, the bench), and each reply due then went out late.
            settle_startup_objects()
            server = LineServer(lines)
            server.start()
        except (ValueError, OSError) as error:
            print(f"invt-gateway simulate: {error}", file=sys.stderr)
            return EXIT_FAILURE
        try:
            for line in lines:
                for path in line.paths:
                    print(path, flush=True)
            line = lines[0]
            adapter = (
                "" if line.adapter.describe() == "none" else f"; adapter: {line.adapter.describe()}"
            )
            if line.relay_s:
                adapter += f"; relay {line.relay_s * 1000:g} ms each way"
            where = ", ".join(path for each in lines for path in each.paths)
            if args.masters > 1:
                where = f"one line shared by {args.masters} masters ({where})"
            print(
                f"simulating {describe_drives(line)} on "
                f"{where} ({args.baud} baud 8{args.parity}{args.stopbits}){adapter}",
                file=sys.stderr,
                flush=True,
            )
            serve_until_signal(lines, signalled)
        finally:
            server.stop()
    return EXIT_OK


def describe_drives(line: SimulatedLine) -> str:
    """ "gd350 drives [1, 2], gd30 drive [3] (2103H = 01F0H, a placeholder: unconfirmed)"."""
    by_model: dict[str, list[int]] = {}
    for address, drive in sorted(line.drives.items()):
        by_model.setdefault(drive.profile.key, []).append(address)
    parts = []
    for key, addresses in by_model.items():
        profile = line.drives[addresses[0]].profile
        text = f"{key} drive{'s' if len(addresses) > 1 else ''} {addresses}"
        if not profile.identification_confirmed:
            text += f" (2103H = {profile.identification[0]:04X}H, a placeholder: unconfirmed)"
        parts.append(text)
    for address, abb in sorted(line.abb_drives.items()):
        parts.append(f"{abb.profile.key} drive [{address}] (ABB Drives profile)")
    return ", ".join(parts)


def late_reply_ms(text: str) -> tuple[float, float]:
    try:
        return late_range(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _slow(text: str) -> tuple[int, tuple[float, float]]:
    address, equals, delay = text.partition("=")
    if not equals:
        raise argparse.ArgumentTypeError(f"{text!r}: give ADDR=MS or ADDR=FROM-TO")
    try:
        return _address(address), late_range(delay)
    except (ValueError, argparse.ArgumentTypeError) as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def build_line(args: argparse.Namespace) -> SimulatedLine:
    models = dict(args.drive)
    addresses = sorted({*(args.address or ([] if models else [1])), *models})
    line = SimulatedLine(
        addresses=addresses,
        models=models,
        model=args.model,
        baudrate=args.baud,
        parity=args.parity,
        stopbits=args.stopbits,
        wire_time=args.wire_time,
        response_delay_ms=args.response_delay_ms,
        device=args.device,
        link=args.link,
        fault_history=dict(args.fault_history),
        wake_early_s=args.wake_early_us / 1e6,
        relay_s=args.relay_ms / 1000,
        masters=args.masters,
    )
    for address, code in args.fault:
        line.inject_fault(address, code)
    for address in args.dead:
        line.set_dead(address, True)
    for address, (low_ms, high_ms) in args.slow:
        line.set_reply_delay(address, low_ms, high_ms)
    if args.burst_ms or args.glitch or args.echo:
        line.set_adapter(burst_ms=args.burst_ms, glitch=args.glitch, echo=args.echo)
    if args.line_faults:
        late_from_ms, late_ms = args.late_reply_ms
        line.set_line_faults(
            args.line_faults, args.line_fault_kinds, args.line_fault_seed, late_ms, late_from_ms
        )
    return line


def serve_until_signal(lines: Sequence[SimulatedLine], signalled: int) -> None:
    """Answer control commands from stdin (unless it is a terminal) until `signalled` is
    readable (SIGTERM or SIGINT arrived)."""
    commands = _command_fd()
    pending = b""
    while True:
        watched = [signalled] if commands is None else [signalled, commands]
        readable, _, _ = select.select(watched, [], [])
        if signalled in readable:
            return
        if commands is not None and commands in readable:
            chunk = os.read(commands, 4096)
            if not chunk:
                commands = None  # EOF: keep serving, just stop listening
                continue
            pending += chunk
            *complete, pending = pending.split(b"\n")
            for raw in complete:
                if raw.strip():
                    answer = run_line_command(lines, raw.decode(errors="replace"))
                    print(answer, flush=True)


@contextlib.contextmanager
def _signal_pipe() -> Iterator[int]:
    """A descriptor that becomes readable on SIGTERM or SIGINT (select can wait for it)."""
    read_fd, write_fd = os.pipe()
    os.set_blocking(write_fd, False)

    def on_signal(number: int, frame: FrameType | None) -> None:
        pass  # the wake-up descriptor has been written already

    # The kernel may deliver the signal to the line's thread, not the main one: then the main
    # thread's select is not interrupted and a Python-level handler would never run. Python's
    # C-level handler writes to the wake-up descriptor in whichever thread the signal lands.
    previous = {number: signal.signal(number, on_signal) for number in _STOP_SIGNALS}
    previous_wakeup = signal.set_wakeup_fd(write_fd)
    try:
        yield read_fd
    finally:
        signal.set_wakeup_fd(previous_wakeup)
        for number, handler in previous.items():
            signal.signal(number, handler)
        os.close(read_fd)
        os.close(write_fd)


_STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT)


def _command_fd() -> int | None:
    """stdin's descriptor when it carries commands: not a terminal, and open."""
    try:
        fd = sys.stdin.fileno()
    except (AttributeError, ValueError, OSError):
        return None
    return None if os.isatty(fd) else fd


def _address(text: str) -> int:
    value = int(text)
    if not 1 <= value <= 247:
        raise argparse.ArgumentTypeError(f"drive address {value} is outside 1..247")
    return value


def _lines(text: str) -> int:
    value = int(text)
    if not 1 <= value <= MAX_LINES:
        raise argparse.ArgumentTypeError(f"{value} lines is outside 1..{MAX_LINES}")
    return value


def _masters(text: str) -> int:
    value = int(text)
    if not 1 <= value <= MAX_MASTERS:
        raise argparse.ArgumentTypeError(f"{value} masters is outside 1..{MAX_MASTERS}")
    return value


def _wake_early_us(text: str) -> float:
    value = float(text)
    if not 0.0 <= value <= 10_000.0:
        raise argparse.ArgumentTypeError(f"wake-early {value:g} us is outside 0..10000")
    return value


def _relay_ms(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"relay delay {text!r} is no number of ms") from None
    if not 0.0 <= value <= 1000.0:
        raise argparse.ArgumentTypeError(f"relay delay {value:g} ms is outside 0..1000")
    return value


def _rate(text: str) -> float:
    value = float(text)
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"fault rate {value} is outside 0..1")
    return value


def _kinds(text: str) -> list[str]:
    kinds = [kind.strip() for kind in text.split(",") if kind.strip()]
    unknown = set(kinds) - KINDS
    if unknown or not kinds:
        raise argparse.ArgumentTypeError(f"line fault kinds are {', '.join(sorted(KINDS))}")
    return kinds


def _glitch(text: str) -> bytes:
    try:
        value = bytes.fromhex(text.removesuffix("H").removesuffix("h"))
    except ValueError:
        value = b""
    if len(value) != 1:
        raise argparse.ArgumentTypeError(f"{text!r}: one byte in hex, e.g. 00 or FF")
    return value


def _drive(text: str) -> tuple[int, str]:
    address, _, model = text.partition("=")
    try:
        key = get_profile(model).key
        if key not in MODELS:
            raise ValueError(model)
        return _address(address), key
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r}: expected ADDR=MODEL with MODEL one of {', '.join(MODELS)}"
        ) from None


def _pair(text: str) -> tuple[int, int]:
    address, _, code = text.partition("=")
    try:
        return _address(address), int(code)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected ADDR=CODE, e.g. 1=35") from None


def _history(text: str) -> tuple[int, list[int]]:
    address, _, codes = text.partition("=")
    try:
        return _address(address), [int(code) for code in codes.split(",") if code]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r}: expected ADDR=CODE,CODE,..., e.g. 3=35,35,35"
        ) from None


def main(argv: Sequence[str] | None = None) -> int:
    """`python -m gateway.instruments.commands.simulate ...`: the same, without the CLI."""
    parser = argparse.ArgumentParser(prog="invt-gateway simulate", description=__doc__)
    add_arguments(parser)
    return handle(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
