"""RS-485 direction control: who switches the transceiver's driver on for a request, and off after.

A 2-wire RS-485 line is half duplex: the master's transceiver must drive the line while its request
goes out and release it before the drive answers. USB adapters do that by themselves. A UART with
an RS-485 transceiver on it (a Raspberry Pi hat, an industrial box's ttyS port) needs the driver
enable (DE) switched around each request, one of two ways:

- `kernel`: the serial driver switches RTS itself around each transmission (the kernel's RS-485
  mode, TIOCSRS485; pyserial's `rs485_mode`). Exact, and the right choice where the driver has it
  (most SoC UARTs: Raspberry Pi's PL011 via `rs485-rts` overlays, SC16IS7xx, 8250/OMAP).
  The kernel takes its delays in whole milliseconds.
- `rts`: the gateway raises RTS, waits `delay_before_tx`, writes the frame, waits until the UART has
  sent its last bit (`tcdrain`, in a worker thread, as it blocks), waits `delay_after_tx` and
  lowers RTS. For ports whose driver lacks RS-485 mode. The drive's response delay (P14.03, at
  least t3.5) must exceed the time from the frame's end to RTS released, or the reply's first
  bytes meet a line still driven by the master.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

import serial
import serial.rs485

from gateway.errors import PortError


class DirectionMode(StrEnum):
    KERNEL = "kernel"
    RTS = "rts"


@dataclass(frozen=True, slots=True)
class DirectionControl:
    mode: DirectionMode
    rts_level_for_tx: bool = True
    """RTS high (True) while transmitting: the usual wiring of DE to RTS through an inverter-free
    path. Some boards invert it."""
    delay_before_tx_s: float = 0.0
    """From driver enabled to the first bit: lets the transceiver settle."""
    delay_after_tx_s: float = 0.0
    """From the last bit sent to driver released: keeps the line driven through the stop bit."""

    def describe(self) -> str:
        level = "high" if self.rts_level_for_tx else "low"
        return f"RS-485 {self.mode} mode, RTS {level} for transmit"


def apply_kernel_mode(port: serial.SerialBase, control: DirectionControl, where: str) -> None:
    """Switch the port into the kernel's RS-485 mode; PortError naming `where` if it refuses."""
    settings = serial.rs485.RS485Settings(
        rts_level_for_tx=control.rts_level_for_tx,
        rts_level_for_rx=not control.rts_level_for_tx,
        delay_before_tx=control.delay_before_tx_s,
        delay_before_rx=control.delay_after_tx_s,
    )
    try:
        port.rs485_mode = settings
    except (ValueError, OSError, serial.SerialException) as exc:
        raise PortError(
            f"{where} refuses the kernel's RS-485 mode ({exc}): its driver can't switch the "
            "transceiver; use rs485.mode: rts (DE wired to RTS) or an adapter with automatic "
            "direction control"
        ) from exc


def set_rts(port: serial.SerialBase, level: bool, where: str) -> None:
    """Drive RTS to `level`; PortError naming `where` if the port has no RTS to drive."""
    try:
        port.rts = level
    except (ValueError, OSError, serial.SerialException) as exc:
        raise PortError(
            f"{where} refuses RTS control ({exc}): rs485.mode: rts needs a UART whose RTS line "
            "drives the transceiver's DE"
        ) from exc
