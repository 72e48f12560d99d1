"""The line's serial port (`gateway.bus.port`), as the bus finds out about it: a pty known for a
virtual line (through a by-id link too), a port that can't be opened or is already another
line's refused with its name, and an adapter pulled between transactions told at once and
named by the next use. On real ptys."""

from __future__ import annotations

import asyncio
import os
import tty
from pathlib import Path

import pytest

from gateway.bus.line import SerialLine
from gateway.bus.port import is_pseudo_terminal
from gateway.config import BusConfig
from gateway.errors import PortError
from gateway.settings import bus_settings
from tests.support import eventually
from tests.unit.bus.line_users import send_after_gap


def line_on(path: str) -> SerialLine:
    config = BusConfig.model_validate({"name": "line1", "port": path, "baudrate": 19200})
    return SerialLine(bus_settings(config).line)


def test_a_pty_is_known_for_a_virtual_line_through_a_link_too(tmp_path: Path) -> None:
    master, slave = os.openpty()
    try:
        link = tmp_path / "usb-FTDI-line1"
        link.symlink_to(os.ttyname(slave))
        assert is_pseudo_terminal(os.ttyname(slave))
        assert is_pseudo_terminal(str(link))
    finally:
        os.close(master)
        os.close(slave)
    assert not is_pseudo_terminal("/dev/null")  # a character device, not a pty
    assert not is_pseudo_terminal("socket://10.0.0.5:4001")
    assert not is_pseudo_terminal(str(tmp_path / "ttyUSB9"))  # not there


async def test_a_port_that_cannot_be_opened_is_refused_with_its_name(tmp_path: Path) -> None:
    missing = str(tmp_path / "ttyUSB9")
    with pytest.raises(PortError, match=f"cannot open {missing}"):
        line_on(missing).open()


async def test_a_port_already_open_for_another_line_is_refused() -> None:
    master, slave = os.openpty()
    tty.setraw(slave)
    path = os.ttyname(slave)
    first = line_on(path)
    first.open()
    try:
        with pytest.raises(PortError, match=f"cannot open {path}"):
            line_on(path).open()
        assert first.is_open  # the first line keeps it
    finally:
        first.close()
        os.close(master)
        os.close(slave)


async def test_an_adapter_pulled_between_transactions_is_told_at_once_and_named_on_next_use() -> (
    None
):
    master, slave = os.openpty()
    tty.setraw(slave)
    path = os.ttyname(slave)
    line = line_on(path)
    told: list[bool] = []
    line.on_port_error = lambda: told.append(line.failed)
    line.open()
    try:
        os.close(master)  # the far end gone: the port hangs up
        await eventually(lambda: told, within_s=2.0, what="the port's failure told")
        assert told == [True]  # once, with nobody waiting on the port
        with pytest.raises(PortError, match=f"read from {path} failed"):
            await asyncio.wait_for(send_after_gap(line, lambda: b"\x01\x03"), 2.0)
        assert not line.is_open  # closed by the use that found out: the bus reopens it
    finally:
        line.close()
        os.close(slave)
