"""`buses`: the RS-485 lines, their serial format, timing, queue and shares of the line's time,
and who switches the transceiver's driver."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator

from gateway.config.sections.section import Section

STANDARD_BAUDRATES = (1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200)


class Rs485Config(Section):
    """Who switches the RS-485 transceiver's driver on around each request (`buses[].rs485`).

    Leave it out for USB adapters, which do it themselves. A UART with a transceiver on it
    (a Raspberry Pi hat, an industrial box's ttyS port) needs one of the two modes."""

    mode: Literal["kernel", "rts"]
    """`kernel`: the serial driver's RS-485 mode (TIOCSRS485) switches RTS; `rts`: the gateway
    toggles RTS around each write and releases it once the UART has drained."""
    rts_level_for_tx: Literal["high", "low"] = "high"
    """RTS level while transmitting (low where the board inverts DE)."""
    delay_before_tx_ms: float = Field(0.0, ge=0, le=1000)
    """From driver enabled to the first bit (kernel mode: whole milliseconds)."""
    delay_after_tx_ms: float = Field(0.0, ge=0, le=1000)
    """From the last bit sent to driver released; must stay below the drives' response delay
    (P14.03) or their replies meet a line still driven (kernel mode: whole milliseconds)."""


class BusConfig(Section):
    name: str = Field(min_length=1, pattern=r"^[A-Za-z0-9_.-]+$")
    """The line's name, which each drive's `bus` names."""
    port: str = Field(min_length=1)
    """A device path (prefer /dev/serial/by-id/...) or a pyserial URL (socket://host:port)."""
    baudrate: int = Field(19200, json_schema_extra={"unit": "bit/s"})
    """One of 1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200: the drives' own (INVT
    P14.01)."""
    parity: Literal["N", "E", "O"] = "E"
    """`N`, `E` or `O`, as the drives' (INVT P14.02, default E81: even parity, 8 data bits, 1
    stop bit)."""
    stopbits: Literal[1, 2] = 1
    """Stop bits, as the drives' (INVT P14.02)."""
    bytesize: Literal[7, 8] = 8
    """Data bits, as the drives' (INVT P14.02)."""
    timeout_ms: float = Field(300.0, gt=0, le=60000)
    """Response timeout per attempt: end of request to first byte of the reply."""
    retries: int = Field(2, ge=0, le=10)
    """Further attempts after a timeout or a bad reply (never after an exception reply)."""
    char_timeout_ms: float = Field(20.0, gt=0, le=5000)
    """Silence inside a reply that ends it (USB adapters deliver bytes in bursts)."""
    drain_ms: float = Field(50.0, ge=0, le=60000)
    """After a timeout, how long to listen for a late reply before the next request."""
    gap_ms: float | None = Field(None, gt=0, le=10000)
    """Inter-frame silence; default t3.5 (3.5 characters, 1.75 ms above 19200 baud)."""
    turnaround_ms: float = Field(100.0, ge=0, le=10000)
    """Silence after a broadcast, while every drive acts on it."""
    queue_size: int = Field(256, ge=1, le=100000)
    """Requests waiting for the line; beyond it a SCADA request is answered exception 0AH (and
    counted)."""
    offline_after: int = Field(3, ge=1, le=1000)
    """Consecutive failed requests after which a drive is offline (answered 0x0B at once)."""
    probe_max_s: float = Field(30.0, gt=0, le=3600)
    """Longest wait between two probes of an offline drive."""
    echo: bool = False
    """The adapter echoes what it sends (no echo suppression): read it back and check it."""
    rs485: Rs485Config | None = None
    """RS-485 direction control for UARTs with a transceiver; None for adapters that do it."""
    write_share: float = Field(0.5, gt=0, le=1)
    """While reads wait, the most of the line's time writes may take (writes still go first)."""
    broadcast_share: float = Field(0.1, gt=0, le=1)
    """While other requests wait, the most of the line's time broadcasts (and their turnaround)
    may take."""
    poll_share: float = Field(0.05, gt=0, le=1)
    """While client reads wait, the most of the line's time the poller's reads may take (with
    no client read waiting they take all of it): every second a full line gives the polls is
    one the clients wait longer. Raise it for fresher telemetry under a SCADA that keeps the
    line busy."""

    @field_validator("baudrate")
    @classmethod
    def _baudrate(cls, value: int) -> int:
        if value not in STANDARD_BAUDRATES:
            raise ValueError(f"must be one of {', '.join(map(str, STANDARD_BAUDRATES))}")
        return value
