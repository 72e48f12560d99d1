"""Text commands for a running simulated line, one per line, each answered by one line.

    fault ADDR CODE     the drive trips with fault CODE      → ok fault 1 35
    clear ADDR          fault reset                          → ok clear 1
    dead ADDR           the address stops answering          → ok dead 2
    alive ADDR          ... and answers again                → ok alive 2
    delay ADDR MS       the address answers MS ms late       → ok delay 1 100
    slow ADDR MS-MS SHARE  that share of its replies late by a random MS-MS → ok slow 1 0-1000 0.05
    stall ADDR S        the address stalls S s, then answers what it took, in order → ok stall 3 1.5
    knows ADDR FC,..|all  frames only these codes (hex), silent to others → ok knows 3 03,04
    drop ADDR RATE      never answers that share of its requests → ok drop 2 0.01
    noise HEX           bytes put on the line now            → ok noise 3
    bursts MS           replies handed over in bursts (0 off) → ok bursts 40
    glitch HEX|off      a spurious byte before each reply    → ok glitch ff
    echo on|off         the adapter echoes every request     → ok echo on
    unplug              the port goes away                   → ok unplug
    unplug-master M     master M's port goes away (--masters) → ok unplug-master 1
    replug              a new port, the link re-pointed      → ok replug /dev/pts/7
    stats               the line's counters                  → ok {"requests": 3, ...}
                        (with --masters N also "collisions" and "masters": each master's
                        path, frames, bytes, collisions and writes)
    writes              (--masters) every 06H write the drives got, with who sent it
                        → ok [[1, 1, 8194, 7], ...] (master, unit, register, value)

With several lines in one process (`simulate --lines N`), `line K COMMAND` carries COMMAND
out on the K-th line (from 1): `line 3 stats`, `line 2 dead 1`. A command without it goes to
the first line.

Anything else, or a command that fails, is answered `error <reason>`.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from typing import Final

from gateway.instruments.simulator.line import SimulatedLine

USAGE: Final = (
    "commands: fault ADDR CODE, clear ADDR, dead ADDR, alive ADDR, delay ADDR MS, "
    "slow ADDR MS-MS SHARE, stall ADDR S, knows ADDR FC,..|all, drop ADDR RATE, noise HEX, "
    "bursts MS, glitch HEX|off, echo on|off, unplug, unplug-master M, replug, stats, writes"
)


def run_line_command(lines: Sequence[SimulatedLine], text: str) -> str:
    """Carry out one command on the line it names (`line K ...`), else on the first."""
    words = text.split()
    if len(words) < 2 or words[0].lower() != "line":
        return run_control_command(lines[0], text)
    try:
        number = int(words[1])
    except ValueError:
        return f"error line takes a line number, not {words[1]!r}"
    if not 1 <= number <= len(lines):
        return f"error no line {number}: there are {len(lines)}"
    return run_control_command(lines[number - 1], " ".join(words[2:]))


def run_control_command(line: SimulatedLine, text: str) -> str:
    """Carry out one command on `line`; the answer starts with "ok" or "error"."""
    words = text.split()
    if not words:
        return f"error empty command; {USAGE}"
    name, arguments = words[0].lower(), words[1:]
    command = _COMMANDS.get(name)
    if command is None:
        return f"error unknown command {name!r}; {USAGE}"
    action, arity = command
    if len(arguments) != arity:
        return f"error {name} takes {arity} argument(s); {USAGE}"
    try:
        detail = action(line, arguments)
    except ValueError as error:
        return f"error {error}"
    except OSError as error:
        return f"error {name} failed: {error}"
    return f"ok {detail}".rstrip()


def _fault(line: SimulatedLine, arguments: list[str]) -> str:
    address, code = int(arguments[0]), int(arguments[1])
    line.inject_fault(address, code)
    return f"fault {address} {code}"


def _clear(line: SimulatedLine, arguments: list[str]) -> str:
    line.clear_fault(int(arguments[0]))
    return f"clear {arguments[0]}"


def _dead(line: SimulatedLine, arguments: list[str]) -> str:
    line.set_dead(int(arguments[0]), True)
    return f"dead {arguments[0]}"


def _alive(line: SimulatedLine, arguments: list[str]) -> str:
    line.set_dead(int(arguments[0]), False)
    return f"alive {arguments[0]}"


def _delay(line: SimulatedLine, arguments: list[str]) -> str:
    address, ms = int(arguments[0]), float(arguments[1])
    line.set_reply_delay(address, ms)
    return f"delay {address} {ms:g}"


def _slow(line: SimulatedLine, arguments: list[str]) -> str:
    address, low, _, high = int(arguments[0]), *arguments[1].partition("-")
    share = float(arguments[2])
    line.set_reply_delay(address, float(low), float(high or low), share)
    return f"slow {address} {arguments[1]} {share:g}"


def _stall(line: SimulatedLine, arguments: list[str]) -> str:
    address, seconds = int(arguments[0]), float(arguments[1])
    line.stall(address, seconds)
    return f"stall {address} {seconds:g}"


def _knows(line: SimulatedLine, arguments: list[str]) -> str:
    address = int(arguments[0])
    functions = None if arguments[1] == "all" else {int(f, 16) for f in arguments[1].split(",")}
    line.know_only(address, functions)
    return f"knows {address} {arguments[1]}"


def _drop(line: SimulatedLine, arguments: list[str]) -> str:
    address, rate = int(arguments[0]), float(arguments[1])
    line.drop_requests(address, rate)
    return f"drop {address} {rate:g}"


def _noise(line: SimulatedLine, arguments: list[str]) -> str:
    data = bytes.fromhex(arguments[0])
    line.write_raw(data)
    return f"noise {len(data)}"


def _bursts(line: SimulatedLine, arguments: list[str]) -> str:
    adapter = line.adapter
    line.set_adapter(burst_ms=float(arguments[0]), glitch=adapter.glitch, echo=adapter.echo)
    return f"bursts {float(arguments[0]):g}"


def _glitch(line: SimulatedLine, arguments: list[str]) -> str:
    glitch = b"" if arguments[0].lower() == "off" else bytes.fromhex(arguments[0])
    adapter = line.adapter
    line.set_adapter(burst_ms=adapter.burst_s * 1000, glitch=glitch, echo=adapter.echo)
    return f"glitch {glitch.hex() or 'off'}"


def _echo(line: SimulatedLine, arguments: list[str]) -> str:
    if arguments[0].lower() not in ("on", "off"):
        raise ValueError("echo takes on or off")
    echo = arguments[0].lower() == "on"
    adapter = line.adapter
    line.set_adapter(burst_ms=adapter.burst_s * 1000, glitch=adapter.glitch, echo=echo)
    return f"echo {'on' if echo else 'off'}"


def _unplug(line: SimulatedLine, arguments: list[str]) -> str:
    line.unplug()
    return "unplug"


def _unplug_master(line: SimulatedLine, arguments: list[str]) -> str:
    line.unplug_master(int(arguments[0]))
    return f"unplug-master {arguments[0]}"


def _replug(line: SimulatedLine, arguments: list[str]) -> str:
    line.replug()
    return f"replug {line.path}"


def _stats(line: SimulatedLine, arguments: list[str]) -> str:
    return json.dumps(line.stats, sort_keys=True)


def _writes(line: SimulatedLine, arguments: list[str]) -> str:
    return json.dumps(line.writes)


_COMMANDS: Final[dict[str, tuple[Callable[[SimulatedLine, list[str]], str], int]]] = {
    "fault": (_fault, 2),
    "clear": (_clear, 1),
    "dead": (_dead, 1),
    "alive": (_alive, 1),
    "delay": (_delay, 2),
    "slow": (_slow, 3),
    "stall": (_stall, 2),
    "knows": (_knows, 2),
    "drop": (_drop, 2),
    "noise": (_noise, 1),
    "bursts": (_bursts, 1),
    "glitch": (_glitch, 1),
    "echo": (_echo, 1),
    "unplug": (_unplug, 0),
    "unplug-master": (_unplug_master, 1),
    "replug": (_replug, 0),
    "stats": (_stats, 0),
    "writes": (_writes, 0),
}
