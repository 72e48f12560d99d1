"""What the gateway's own hardware does to the bytes it receives, as real adapters do it.

| effect  | what the master receives                                                      |
|---------|-------------------------------------------------------------------------------|
| bursts  | received bytes handed over in batches every `burst_s` (a USB adapter's latency |
|         | timer, a serial device server packing TCP segments): a reply arrives in pieces |
| glitch  | one spurious byte (often 00H or FFH) just before each reply: a transceiver     |
|         | glitching as the bus turns around (driver-enable switching)                    |
| echo    | its own request handed back as it goes out: a 2-wire adapter without echo      |
|         | suppression                                                                    |

Bursts are simulated at their worst for the master: a batch boundary falls in the middle of every
reply, so every reply is cut and its second part comes `burst_s` after the first.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class AdapterEffects:
    burst_s: float = 0.0
    """Batch period; 0 delivers each reply whole the moment its last byte has left the wire."""
    glitch: bytes = b""
    """Put before every reply (one byte: 00H or FFH, typically); empty for none."""
    echo: bool = False

    def describe(self) -> str:
        effects = []
        if self.burst_s:
            effects.append(f"bursts every {self.burst_s * 1000:g} ms")
        if self.glitch:
            effects.append(f"glitch {self.glitch.hex(' ').upper()}H before each reply")
        if self.echo:
            effects.append("echo of each request")
        return ", ".join(effects) or "none"

    def deliveries(
        self, reply: bytes, last_byte_s: float, char_s: float
    ) -> list[tuple[float, bytes]]:
        """When the master gets which part of `reply`, whose last byte leaves at `last_byte_s`.

        The glitch takes the last character time before the reply (it comes during the turnaround,
        so it doesn't delay the reply). Returns (time, bytes) pairs in order.
        """
        if not self.burst_s or len(reply) < 2:
            return [(last_byte_s, self.glitch + reply)]
        first_byte_s = last_byte_s - len(reply) * char_s
        cut = len(reply) // 2
        tick = first_byte_s + cut * char_s  # a batch boundary in the middle of the reply
        pieces: list[tuple[float, bytes]] = [(tick, self.glitch + reply[:cut])]
        sent = cut
        while sent < len(reply):
            tick += self.burst_s
            # Bytes whose last bit has left by this tick go in this batch.
            upto = min(len(reply), int((tick - first_byte_s) / char_s + 1e-9))
            if upto > sent:
                pieces.append((tick, reply[sent:upto]))
                sent = upto
        return pieces
