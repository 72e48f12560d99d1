"""The `opcua` cases' OPC UA side: the server's section of the gateway's configuration, and
the SCADA clients subscribed to every drive's values, as one process of their own
(`opcua_clients`), so that their work is not counted in the gateway's CPU nor takes the
bench's own loop from the Modbus-TCP readers."""

from __future__ import annotations

import asyncio
import contextlib
import json
import select
import struct
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

from gateway.instruments.die_with_parent import die_with_parent

HOST: Final = "127.0.0.1"
PUBLISHING_INTERVAL_MS: Final = 1000
VALUES_PER_DRIVE: Final = 48
"""The issue's figure, at most: an INVT drive has fewer value variables (22, all polled by the
bench's groups); each session takes those the poller fills first."""
READY_TIMEOUT_S: Final = 120.0
"""Five sessions made (Basic256Sha256 Sign & Encrypt), each browsing and subscribing to 32
drives, on a shared two-core machine: a few seconds, this is the bound."""


def server_section(folder: Path, port: int, gateway_id: str) -> dict[str, Any]:
    """`opcua:` as a plant would have it for SCADA on another machine: Sign & Encrypt, the
    server's files and the trusted clients in `folder`; the clients read only, as anonymous
    (a login is one scrypt check per session at connect, nothing during the measured time).
    The server's certificate is made here, as the gateway makes its own on a first start:
    given as files, they must exist."""
    from gateway.opcua.certificates import ensure_server_certificate  # the opcua extra's

    certificate, key = folder / "server-cert.der", folder / "server-key.pem"
    ensure_server_certificate(certificate, key, f"urn:invt-gateway:{gateway_id}", "bench", HOST)
    return {
        "enabled": True,
        "host": HOST,
        "port": port,
        "security": ["Basic256Sha256_SignAndEncrypt"],
        "anonymous": True,
        "certificate_file": str(certificate),
        "private_key_file": str(key),
        "trusted_clients_dir": str(folder / "trusted"),
        "rejected_clients_dir": str(folder / "rejected"),
    }


ACCELERATION_TIME = 0x000B  # P00.11, 0.1 s
SLOWEST_RAMP = 36000  # 3600.0 s from 0 Hz to P00.03's 50 Hz: 0.014 Hz/s
CONTROL_WORD, RUN_FORWARD = 0x2000, 1


async def run_slowly(port: int, units: list[int]) -> None:
    """Every drive run forward on its slowest ramp (through the gateway's Modbus-TCP port):
    its frequency, speed, voltage and power change at every poll for the whole case, as a
    running plant's do, so the subscriptions have changes to publish. Done alike with and
    without OPC UA: the readers' line carries the same."""
    reader, writer = await asyncio.open_connection(HOST, port)
    for number, unit in enumerate(units):
        for register, value in ((ACCELERATION_TIME, SLOWEST_RAMP), (CONTROL_WORD, RUN_FORWARD)):
            pdu = struct.pack(">BHH", 6, register, value)
            writer.write(struct.pack(">HHHB", number, 0, len(pdu) + 1, unit) + pdu)
            _, _, length, _ = struct.unpack(">HHHB", await reader.readexactly(7))
            reply = await reader.readexactly(length - 1)
            if reply != pdu:
                raise RuntimeError(f"drive {unit} refused {pdu.hex(' ')}: {reply.hex(' ')}")
    writer.close()
    await writer.wait_closed()


def endpoint(port: int) -> str:
    return f"opc.tcp://{HOST}:{port}/invt-gateway"


@dataclass(slots=True)
class ClientsProcess:
    process: subprocess.Popen[str]
    items: int
    """Monitored items per session, as the server took them."""

    def finish(self) -> dict[str, int]:
        """Ends the clients (their stdin closed); what they saw: items and notifications."""
        assert self.process.stdin is not None
        assert self.process.stdout is not None
        self.process.stdin.close()
        line = self.process.stdout.readline()
        self.process.wait(30)
        return {k: int(v) for k, v in json.loads(line).items()}


@contextlib.contextmanager
def opcua_clients(port: int, folder: Path, sessions: int) -> Iterator[ClientsProcess]:
    """`sessions` asyncua client sessions in one process, each subscribed to
    `VALUES_PER_DRIVE` values of every drive at `PUBLISHING_INTERVAL_MS`; yielded once all
    have subscribed."""
    args = [sys.executable, "-m", "gateway.instruments.bench.opcua_clients", endpoint(port)]
    args += [str(folder), str(sessions), str(PUBLISHING_INTERVAL_MS), str(VALUES_PER_DRIVE)]
    process = subprocess.Popen(
        args,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
        preexec_fn=die_with_parent(),
    )
    try:
        assert process.stdout is not None
        ready, _, _ = select.select([process.stdout], [], [], READY_TIMEOUT_S)
        line = process.stdout.readline() if ready else ""
        if not line.startswith("{"):
            raise RuntimeError(f"the OPC UA clients did not subscribe: {line!r}")
        yield ClientsProcess(process, int(json.loads(line)["items"]))
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
