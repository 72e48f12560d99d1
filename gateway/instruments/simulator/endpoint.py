"""The simulator's end of the serial line: a pty it creates, or an existing serial device.

A pty pair stands for an RS-485 adapter: the gateway opens the slave side by its path. Both ends
are raw (no echo, no line editing, all 8 bits), and the simulator keeps its own descriptor of the
slave open, so that the gateway closing and reopening the port never hangs the master up (EIO).
Closing the master (unplug) is what makes the gateway's open port fail, like a USB adapter pulled.
"""

from __future__ import annotations

import contextlib
import os
import tty
from pathlib import Path

import serial


class Endpoint:
    """A file descriptor to read requests from and write replies to, and the path to give out."""

    def __init__(
        self,
        fd: int,
        path: str,
        keep_open: tuple[int, ...] = (),
        port: serial.Serial | None = None,
    ) -> None:
        self.fd = fd
        self.path = path
        self._keep_open = keep_open
        self._port = port

    @classmethod
    def open_pty(cls) -> Endpoint:
        master, slave = os.openpty()
        tty.setraw(master)
        tty.setraw(slave)
        os.set_blocking(master, False)
        return cls(master, os.ttyname(slave), keep_open=(slave,))

    @classmethod
    def open_device(cls, path: str, baudrate: int, parity: str, stopbits: int) -> Endpoint:
        port = serial.Serial(path, baudrate=baudrate, parity=parity, stopbits=stopbits, timeout=0)
        return cls(port.fileno(), path, port=port)

    def close(self) -> None:
        if self._port is not None:
            self._port.close()
        else:
            for fd in (self.fd, *self._keep_open):
                with contextlib.suppress(OSError):
                    os.close(fd)


def point_link(link: str, target: str) -> None:
    """Make `link` a symlink to `target`, replacing an older link atomically."""
    path = Path(link)
    if path.exists() and not path.is_symlink():
        raise FileExistsError(f"{link} exists and is not a symlink: not replacing it")
    staging = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    with contextlib.suppress(FileNotFoundError):
        staging.unlink()
    staging.symlink_to(target)
    staging.replace(path)


def remove_link(link: str) -> None:
    """Remove `link` if it is a symlink (what udev does to /dev/serial/by-id on unplug)."""
    path = Path(link)
    if path.is_symlink():
        path.unlink()
