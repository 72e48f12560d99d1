"""Replies spoilt the ways a real RS-485 line spoils them, at a chosen rate, reproducibly.

| kind          | what the master receives                                           |
|---------------|--------------------------------------------------------------------|
| crc           | the reply with one CRC byte flipped                                |
| truncated     | only the first part of the reply                                   |
| extra_bytes   | the reply followed by 1-3 stray bytes                              |
| wrong_address | a well-formed reply (good CRC) from another address                |
| late          | the right reply, `late_s` after it was due (or at random from       |
|               | `late_from_s` to `late_s`): a drive busy with an EEPROM write      |
| silence       | nothing                                                            |
"""

from __future__ import annotations

import random
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Final

from gateway.modbus.crc import crc_bytes

KINDS: Final = frozenset({"crc", "truncated", "extra_bytes", "wrong_address", "late", "silence"})


@dataclass(frozen=True)
class Spoilt:
    kind: str
    frame: bytes | None
    """What goes on the line instead of the reply; None for silence."""
    extra_delay_s: float = 0.0


class LineFaults:
    def __init__(self) -> None:
        self.rate = 0.0
        self.kinds: tuple[str, ...] = ()
        self.late_s = 0.5
        self.late_from_s = 0.5
        self._random = random.Random()

    def configure(
        self,
        rate: float,
        kinds: Iterable[str] | None = None,
        seed: int | None = None,
        late_s: float = 0.5,
        late_from_s: float | None = None,
    ) -> None:
        chosen = sorted(KINDS if kinds is None else set(kinds))  # sorted: a seed replays exactly
        unknown = set(chosen) - KINDS
        if unknown:
            raise ValueError(f"unknown line fault kinds {sorted(unknown)}: use {sorted(KINDS)}")
        if not 0.0 <= rate <= 1.0:
            raise ValueError(f"fault rate {rate} is outside 0..1")
        self.rate = rate
        self.kinds = tuple(chosen)
        if late_from_s is not None and not 0.0 <= late_from_s <= late_s:
            raise ValueError(f"late replies from {late_from_s} s to {late_s} s: not a range")
        self.late_s = late_s
        self.late_from_s = late_s if late_from_s is None else late_from_s
        self._random = random.Random(seed)

    def maybe_spoil(self, reply: bytes) -> Spoilt | None:
        """Spoil `reply` with probability `rate`; None leaves it intact."""
        if not self.kinds or self._random.random() >= self.rate:
            return None
        kind = self._random.choice(self.kinds)
        return Spoilt(kind, *self._spoil(kind, reply))

    def _spoil(self, kind: str, reply: bytes) -> tuple[bytes | None, float]:
        if kind == "crc":
            return reply[:-1] + bytes((reply[-1] ^ 0xFF,)), 0.0
        if kind == "truncated":
            return reply[: self._random.randint(1, len(reply) - 1)], 0.0
        if kind == "extra_bytes":
            count = self._random.randint(1, 3)
            return reply + self._random.randbytes(count), 0.0
        if kind == "wrong_address":
            body = bytes((reply[0] % 247 + 1,)) + reply[1:-2]
            return body + crc_bytes(body), 0.0
        if kind == "late":
            if self.late_from_s == self.late_s:
                return reply, self.late_s
            return reply, self._random.uniform(self.late_from_s, self.late_s)
        return None, 0.0


def late_range(text: str) -> tuple[float, float]:
    """A late reply's delay in milliseconds as a user gives it: "500" (always 500 ms late) or
    "0-1000" (drawn at random from that range)."""
    low, _, high = text.partition("-")
    try:
        values = (float(low), float(high or low))
    except ValueError:
        raise ValueError(f"{text!r}: give MS or FROM-TO, e.g. 0-1000") from None
    if not 0 <= values[0] <= values[1]:
        raise ValueError(f"{text!r}: FROM-TO with 0 <= FROM <= TO")
    return values
