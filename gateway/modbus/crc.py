"""CRC-16/MODBUS: polynomial A001H (reflected 8005H), initial value FFFFH, sent low byte first.

Every frame's CRC is worked out in Python, two bytes a step: the register is 16 bits wide, so
feeding it 16 bits shifts the whole of it out, and what it holds then depends on nothing but
`register ^ word`, one lookup in a 65,536-entry table (`_PAIRS`, 128 KiB, built from the
byte table in some 20 ms at import). Half the steps of a byte table, each without its shift,
mask and XOR, and the words taken out of the frame by one `struct` call: a 2-word read's two
CRCs (request and reply) cost about 3,000 instructions less a transaction (callgrind), a
16-word read's more. Pure Python, so it installs anywhere; no maintained CRC library has wheels
for 32-bit ARM.

A frame followed by its own CRC (low byte first) leaves the register at 0: `crc_ok` checks a
frame so, in one pass over it, without cutting the CRC off first.
"""

from __future__ import annotations

import struct
from array import array
from collections.abc import Iterable


def _build_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
        table.append(crc)
    return tuple(table)


_TABLE = _build_table()
"""The register after one byte: `(crc >> 8) ^ _TABLE[(crc ^ byte) & 0xFF]`."""


def _build_pairs() -> array[int]:
    """The register after two bytes, low byte first, from `register ^ word` alone."""
    table = _TABLE
    once = [(x >> 8) ^ table[x & 0xFF] for x in range(65536)]
    return array("H", [(c >> 8) ^ table[c & 0xFF] for c in once])


_PAIRS = _build_pairs()
_WORDS = [struct.Struct(f"<{count}H") for count in range(129)]
"""A frame's little-endian words, by how many (a frame is at most 256 bytes): one call takes
them all out, with no view or slice made per frame."""


def crc16(data: bytes | bytearray | memoryview) -> int:
    """Return the CRC of `data` as an integer (its low byte goes on the wire first)."""
    return crc16_from(0xFFFF, data, 0)


def crc16_from(register: int, data: bytes | bytearray | memoryview, start: int) -> int:
    """The CRC register after `data[start:]`, from what it held after `data[:start]`: a frame
    whose first bytes are known before it comes (a reply's address, function and byte count)
    has their part worked out once, not in every check of it."""
    size = len(data) - start
    register = crc16_words(register, words_of(size >> 1).unpack_from(data, start))
    if size & 1:
        register = (register >> 8) ^ _TABLE[(register ^ data[-1]) & 0xFF]
    return register


def crc16_words(register: int, words: Iterable[int]) -> int:
    """The CRC register after `words`, a frame's bytes taken two at a time, low byte first
    (`words_of`), from `register`: for a caller that knows the frame's length in advance."""
    pairs = _PAIRS
    for word in words:
        register = pairs[register ^ word]
    return register


def words_of(count: int) -> struct.Struct:
    """What takes `count` little-endian words out of a frame (`crc16_words`), in one call."""
    return _WORDS[count] if count < len(_WORDS) else struct.Struct(f"<{count}H")


def crc_bytes(data: bytes | bytearray | memoryview) -> bytes:
    """The two CRC bytes to append to `data`, low byte first."""
    return crc16(data).to_bytes(2, "little")


def crc_ok(frame: bytes | bytearray | memoryview) -> bool:
    """True when the last two bytes of `frame` are the CRC of the bytes before them."""
    return len(frame) >= 3 and crc16(frame) == 0
