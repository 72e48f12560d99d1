"""`bench --instructions`: the gateway's instructions per bus transaction, counted by callgrind.

CPU time per transaction varies +-20 % from run to run on a shared 2-core machine, so an A/B of
a performance change drowns in noise. The user-space instructions a process executes don't vary
with what else the machine does: valgrind's callgrind counts them, and the same code gives the
same count within ~0.5 %. The count is for comparing two versions of the code, not a cost in
time: kernel work (the socket and port writes), cache misses and waits are not in it.

One measurement is two runs of the gateway under callgrind, one Modbus-TCP client doing `low`
and then `high` sequential reads. Start-up and shutdown are the same in both (some 1.7 billion
instructions: Python's imports) and cancel out of (Ir(high) - Ir(low)) / (high - low).
"""

from __future__ import annotations

import os
import platform
import shutil
import struct
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from gateway import ENGINE_ROOM
from gateway.errors import InstructionCountError, LineError
from gateway.instruments.bench.cases import Case, gateway_config
from gateway.instruments.bench.prepare import SET_POINT
from gateway.instruments.bench.processes import free_port, gateway, simulator
from gateway.tools.masters import TcpMaster

BAUDRATE = 1200
"""Under callgrind the gateway runs ~50x slower: some 15-20 ms of work per transaction. The
t3.5 gap at 1200 baud (32 ms) stays longer than that, so each request still waits in the queue
for the gap timer and the reply still ends its transaction in the port's reader callback: the
path taken at full speed. At a faster rate the work would outlast the gap, and the count would
be of another path."""
CASE = Case("no wire delay", BAUDRATE, 2, 1, no_wire=True)
"""The bench's case of that name (the gateway's own work, nothing on the line to hide it)."""
UNIT = CASE.units(0)[0]
START_TIMEOUT_S = 300.0
"""Python's start-up under callgrind takes 20-40 s on an idle 2-core machine; far more under
load, and a slow start is no error here."""
STOP_TIMEOUT_S = 120.0
"""After SIGTERM: the gateway's graceful stop under callgrind, then callgrind writes its file."""
REPLY_TIMEOUT_UNDER_CALLGRIND_MS = 10_000
"""The bus's reply timeout in the counted run. At ~50x slower, the default 300 ms is 6 ms of the
gateway's work at full speed: on a loaded box a reply the drive sent at once was read after it
(transaction 2 of 30 answered 0BH in a CI run). Arming a timer costs the same for any deadline,
so the count is of the same path."""
REPLY_TIMEOUT_S = 30.0
MEANING = (
    "user-space instructions of the gateway process per bus transaction, counted by callgrind; "
    "kernel time not included; the same code gives the same count within ~0.5 %"
)
MISSING = "invt-gateway bench --instructions needs valgrind: install Debian's `valgrind` package"
UNPINNED = (
    "invt-gateway bench --instructions: address randomisation can't be turned off here "
    "(setarch --addr-no-randomize refused): counts of the same code vary ~1 %, not ~0.5 %"
)
READ = struct.pack(">BHH", 3, SET_POINT, CASE.words)
REPLY_LENGTH = 2 + 2 * CASE.words
"""Function, byte count and the registers."""


@dataclass(frozen=True, slots=True)
class Count:
    """One measurement: the gateway's instructions with `low` and with `high` transactions."""

    low: int
    high: int
    low_instructions: int
    high_instructions: int

    @property
    def transactions(self) -> int:
        return self.high - self.low

    @property
    def per_transaction(self) -> float:
        return (self.high_instructions - self.low_instructions) / self.transactions


def measure(
    valgrind: str, low: int, high: int, pinning: Sequence[str] = (), source: str | None = None
) -> Count:
    """`source`: another checkout's top folder, whose gateway is run instead of this one."""
    return Count(
        low, high, run(valgrind, low, pinning, source), run(valgrind, high, pinning, source)
    )


def fixed_addresses() -> list[str]:
    """A prefix that turns address randomisation off, or none where the kernel refuses it (a
    container's seccomp profile may): CPython's method cache is indexed by addresses, so with
    them its misses move from run to run. Measured here (300 transactions, a few runs each):
    a spread of ~2 % with addresses and string hashes free, ~1 % with the hashes fixed,
    0.3-0.5 % with both fixed."""
    setarch = shutil.which("setarch")  # util-linux, on every Debian
    if setarch is None:
        return []
    command = [setarch, platform.machine(), "--addr-no-randomize"]
    refused = subprocess.run([*command, "true"], capture_output=True).returncode
    return [] if refused else command


def run(
    valgrind: str, transactions: int, pinning: Sequence[str] = (), source: str | None = None
) -> int:
    """The gateway's instructions, start to exit, having carried `transactions` reads;
    `pinning` from `fixed_addresses()`; `source` as for `measure`."""
    addresses = list(range(1, CASE.drives + 1))
    with (
        tempfile.TemporaryDirectory(prefix="invt-callgrind-") as folder,
        simulator(addresses, BAUDRATE, [], 0.0, CASE.simulator_args) as line,
    ):
        out = Path(folder) / "callgrind.out"
        port = free_port()
        config = gateway_config(CASE, [line.path], port, metrics_port=free_port())
        for bus in config["buses"]:
            bus["timeout_ms"] = REPLY_TIMEOUT_UNDER_CALLGRIND_MS
        # String hashes fixed: dicts and sets laid out alike in every run.
        prefix = [*pinning, "env", "PYTHONHASHSEED=0"]
        if source is not None:  # `python -m` imports from its working folder first
            prefix.append(f"PYTHONPATH={Path(source).resolve()}")
        prefix += [valgrind, "--tool=callgrind", f"--callgrind-out-file={out}"]
        folder_of_code = None if source is None else str(Path(source).resolve())
        with gateway(
            config, port, prefix, START_TIMEOUT_S, STOP_TIMEOUT_S, cwd=folder_of_code
        ) as process:
            read_sequentially(port, transactions)
        return instructions(out, process.process.returncode)


def engine_room(source: str | None = None) -> str:
    """How the gateway's engine room runs where the counted gateway is imported from (this
    package's, or `source`'s): compiled by mypyc, or Python and why (`gateway.ENGINE_ROOM`)."""
    if source is None:  # the gateway process imports this very package, with this environment
        return ENGINE_ROOM
    folder = str(Path(source).resolve())
    asked = subprocess.run(
        [sys.executable, "-c", "import gateway; print(gateway.ENGINE_ROOM)"],
        capture_output=True,
        text=True,
        cwd=folder,
        env={**os.environ, "PYTHONPATH": folder},
        check=False,
    )
    return asked.stdout.strip() or f"unknown ({asked.stderr.strip()})"


def read_sequentially(port: int, transactions: int) -> None:
    """`transactions` reads from one client, each sent once the one before is answered, each
    reply checked: the read's answer, of the right length, no exception."""
    number = 0
    try:
        client = TcpMaster("127.0.0.1", port, REPLY_TIMEOUT_S)
        try:
            for number in range(transactions):
                _check(client.request(UNIT, READ), number, transactions)
        finally:
            client.close()
    except LineError as error:  # refused, reset, no reply in time, another request's answer
        raise InstructionCountError(
            f"transaction {number + 1} of {transactions}: {error}"
        ) from error


def _check(pdu: bytes, number: int, transactions: int) -> None:
    if not pdu or pdu[0] != READ[0]:
        raise InstructionCountError(
            f"transaction {number + 1} of {transactions}: wrong reply "
            f"{pdu.hex(' ')} (an exception, or not the read's answer)"
        )
    if len(pdu) != REPLY_LENGTH or pdu[1] != REPLY_LENGTH - 2:
        raise InstructionCountError(
            f"transaction {number + 1} of {transactions}: reply of {len(pdu)} bytes, "
            f"{REPLY_LENGTH} expected: {pdu.hex(' ')}"
        )


def instructions(out: Path, returncode: int | None) -> int:
    """Ir from callgrind's file: `totals:` at its end (`summary:` in older versions)."""
    found = [
        int(line.split()[1])
        for line in (out.read_text().splitlines() if out.exists() else [])
        if line.startswith(("totals:", "summary:"))
    ]
    if not found:
        raise InstructionCountError(
            f"callgrind wrote no count (the gateway exited with {returncode}; a gateway killed "
            f"after {STOP_TIMEOUT_S:.0f} s leaves none)"
        )
    return max(found)


def median(counts: list[Count]) -> Count:
    return sorted(counts, key=lambda c: c.per_transaction)[len(counts) // 2]


def report(counts: list[Count]) -> list[str]:
    """The median run as a table, each run's figure when there are several, what it means."""
    chosen = median(counts)
    lines = [
        f"{'case':<16}  {'baud':>5}  {'transactions':>12}  {'instructions/tx':>15}",
        f"{CASE.name:<16}  {BAUDRATE:>5}  {chosen.transactions:>12}  "
        f"{chosen.per_transaction:>15,.0f}",
        "",
    ]
    if len(counts) > 1:
        figures = [c.per_transaction for c in counts]
        spread = (max(figures) - min(figures)) / chosen.per_transaction
        each = ", ".join(f"{f:,.0f}" for f in figures)
        lines.append(f"median of {len(counts)} runs: {each} (spread {spread:.2%})")
    return [*lines, MEANING]


def as_json(counts: list[Count]) -> dict[str, Any]:
    chosen = median(counts)
    return {
        "case": CASE.name,
        "baud": BAUDRATE,
        "transactions": chosen.transactions,
        "instructions/tx": chosen.per_transaction,
        "runs": [c.per_transaction for c in counts],
        "meaning": MEANING,
    }
