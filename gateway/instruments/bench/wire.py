"""The physical limit of the line for one kind of transaction.

One transaction occupies the line for:
    t3.5 gap  +  request bytes  +  the drive's response delay  +  reply bytes
plus, with a relay between the gateway's port and the wire (a USB adapter's timer, a serial
device server), the relay's delay each way: the request reaches the drive that much later, the
reply the gateway that much later, and the gateway's t3.5 starts only when it has the reply;
where a byte takes (start + 8 data + parity + stop bits) / baud seconds and the drive's response
delay is at least t3.5 (a drive can't answer inside the silence that ends the request). Nothing the
gateway does can make a transaction shorter; everything it does badly makes it longer.
"""

from __future__ import annotations

from dataclasses import dataclass

from gateway.modbus.timing import CharacterFormat

READ_REQUEST_BYTES = 8  # address, 03H, start (2), count (2), CRC (2)


def read_reply_bytes(words: int) -> int:
    """address, 03H, byte count, 2 bytes per word, CRC (2)."""
    return 5 + 2 * words


@dataclass(frozen=True, slots=True)
class WireBudget:
    char_format: CharacterFormat
    request_bytes: int
    reply_bytes: int
    response_delay_s: float
    adapter_delay_s: float = 0.0
    """What the master's adapter adds to every transaction: with replies handed over in bursts,
    the wait for the part of each reply held back until the next burst."""
    relay_s: float = 0.0
    """The relay's delay each way between the gateway's port and the wire."""
    wire: bool = True
    """False: bytes take no time and the drive answers at once (a pty without wire-time
    emulation); only the gap the gateway keeps before each request is left."""

    @property
    def transaction_s(self) -> float:
        fmt = self.char_format
        if not self.wire:
            return fmt.t35_s + 2 * self.relay_s
        delay = max(self.response_delay_s, fmt.t35_s)
        wire = fmt.t35_s + fmt.wire_time_s(self.request_bytes + self.reply_bytes) + delay
        return wire + self.adapter_delay_s + 2 * self.relay_s

    @property
    def max_per_s(self) -> float:
        return 1.0 / self.transaction_s


def read_budget(
    baudrate: int,
    words: int,
    response_delay_s: float,
    parity: str = "E",
    burst_s: float = 0.0,
    wire: bool = True,
    relay_s: float = 0.0,
) -> WireBudget:
    fmt = CharacterFormat(baudrate, parity)
    reply = read_reply_bytes(words)
    # The simulated adapter cuts each reply in the middle and hands the rest over one burst
    # period later (`gateway.instruments.simulator.adapter`), instead of as it leaves the wire.
    held_back = burst_s - fmt.wire_time_s(reply - reply // 2) if burst_s else 0.0
    return WireBudget(
        fmt,
        READ_REQUEST_BYTES,
        reply,
        response_delay_s,
        max(held_back, 0.0),
        relay_s=relay_s,
        wire=wire,
    )
