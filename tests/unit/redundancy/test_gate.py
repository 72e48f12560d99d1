"""The write gate a redundant active puts in front of its ports (`gateway.redundancy.gate`):
open, bytes go out; closed (another master heard), no byte does, whichever write is asked."""

from __future__ import annotations

import os
import time
import tty

import pytest

from gateway.bus.port import open_port
from gateway.bus.receiver import Receiver
from gateway.config.sections.buses import BusConfig
from gateway.errors import PortError
from gateway.modbus.rtu import build_frame
from gateway.redundancy.gate import WriteGate
from gateway.settings.lines import bus_settings

READ = build_frame(1, bytes.fromhex("0330000002"))


def pending(fd: int, expected: int = 0, within_s: float = 2.0) -> bytes:
    """What the pty's other end has got: at least `expected` bytes if they come within
    `within_s` (a pty hands two writes over in one read or in two, later on a busy machine)."""
    got = bytearray()
    deadline = time.monotonic() + within_s
    while True:
        try:
            got += os.read(fd, 1024)
        except BlockingIOError:
            if len(got) >= expected or time.monotonic() > deadline:
                return bytes(got)
            time.sleep(0.005)


async def test_a_closed_gate_lets_no_byte_through() -> None:
    master, slave = os.openpty()
    tty.setraw(master)
    os.set_blocking(master, False)
    try:
        line = bus_settings(BusConfig.model_validate({"name": "l", "port": os.ttyname(slave)})).line
        port = open_port(line, Receiver(line), lambda data: None, lambda: None)
        gate = WriteGate()
        gate.install(port)
        try:
            assert port.write_now(READ) == len(READ)
            await port.write(READ)
            assert pending(master, 2 * len(READ)) == READ + READ
            gate.close("another master is on the line")
            with pytest.raises(PortError, match="nothing sent: another master is on the line"):
                port.write_now(READ)
            with pytest.raises(PortError):
                await port.write(READ)
            with pytest.raises(PortError):
                port.write_whole(READ)
            assert pending(master) == b""
            # A port the line opens after the gate closed (a reopen) is silenced from the start.
            port.close()
            again = open_port(line, Receiver(line), lambda data: None, lambda: None)
            gate.install(again)
            try:
                with pytest.raises(PortError, match="nothing sent"):
                    again.write_now(READ)
            finally:
                again.close()
        finally:
            port.close()
    finally:
        os.close(master)
        os.close(slave)
