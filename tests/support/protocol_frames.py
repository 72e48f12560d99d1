"""PROTOCOL.md's "Frames to test against", the one copy the tests share.

As (request, reply) hex pairs, in an order where each write sets up what a later read expects;
a drive at address 3 must hold the fault history 35 x 6 (P07.27-P07.32) for the 03 07 1B read.
"""

from __future__ import annotations

READ_BACK_REQUEST = "01 03 01 14 00 01 C5 F2"
"""Ours, not PROTOCOL.md's: it reads P01.20 back, PROTOCOL gives only the reply."""

PROTOCOL_EXCHANGES = [
    ("01 03 00 04 00 02 85 CA", "01 03 04 13 88 00 00 7E 9D"),
    ("01 08 00 00 12 AB AD 14", "01 08 00 00 12 AB AD 14"),
    ("02 06 00 04 13 88 C5 6E", "02 06 00 04 13 88 C5 6E"),
    ("02 10 00 04 00 02 04 13 88 00 32 F8 63", "02 10 00 04 00 02 00 3A"),
    ("01 06 00 01 00 03 98 0B", "01 86 04 43 A3"),
    ("01 03 21 00 00 01 8E 36", "01 03 02 00 03 F8 45"),
    ("03 03 07 1B 00 06 B5 59", "03 03 0C 00 23 00 23 00 23 00 23 00 23 00 23 5F D2"),
    ("03 06 20 00 00 01 42 28", "03 06 20 00 00 01 42 28"),
    ("03 06 00 03 27 10 62 14", "03 06 00 03 27 10 62 14"),
    ("01 10 20 00 00 02 04 00 01 03 E8 3B 10", "01 10 20 00 00 02 4A 08"),
    ("01 10 00 0B 00 02 04 00 64 00 C8 F2 55", "01 10 00 0B 00 02 30 0A"),
    ("01 06 01 14 00 32 49 E7", "01 06 01 14 00 32 49 E7"),
    (READ_BACK_REQUEST, "01 03 02 00 32 39 91"),
]

PROTOCOL_FRAMES = list(
    dict.fromkeys(
        frame for pair in PROTOCOL_EXCHANGES for frame in pair if frame != READ_BACK_REQUEST
    )
)
"""Every frame of PROTOCOL.md's table, once each (echoes are the same frame as their request)."""
