"""RTS switched by the line around each request (`rs485.mode: rts`, `gateway.bus.direction`).

The driver is switched on as the request starts, the frame written (after the transceiver's
set-up delay, if any), and the driver released once the UART has sent the last bit and the hold
after it has passed: the moment the response timeout counts from.
"""

from __future__ import annotations

import time

from gateway.bus.direction import DirectionControl
from gateway.bus.line_timer import LineTimer
from gateway.bus.port import Port


class RtsSwitch:
    """One line's RTS, raised for each request and lowered after it."""

    def __init__(self, control: DirectionControl, port: Port, timer: LineTimer) -> None:
        self.control = control
        self._port = port
        self._timer = timer

    def start(self, frame: bytes) -> float:
        """Switch the driver on; write at once unless the transceiver needs a set-up delay.
        When `finish` may write the frame (0.0: written)."""
        self._port.set_rts(self.control.rts_level_for_tx)
        if self.control.delay_before_tx_s > 0:
            # Counted from the switch, not from when the attempt started: the set-up time is
            # the transceiver's after its driver came on, and switching RTS is an ioctl.
            return time.monotonic() + self.control.delay_before_tx_s
        self._port.write_whole(frame)
        return 0.0

    async def finish(self, frame: bytes, write_at: float, wire_s: float) -> float:
        """Write (after the set-up delay), wait for the UART to drain, hold, release the driver.

        Returns when the last bit left (the drain), the moment the response timeout counts from.
        """
        control = self.control
        if write_at:
            await self._timer.sleep_until(write_at)
            self._port.write_whole(frame)
        await self._port.drained(wire_s + 1.0)
        sent = time.monotonic()
        if control.delay_after_tx_s > 0:
            await self._timer.sleep_until(sent + control.delay_after_tx_s)
        self._port.set_rts(not control.rts_level_for_tx)
        return sent
