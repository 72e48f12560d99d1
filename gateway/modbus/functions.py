"""Function codes as data: what a request does and how long its reply is.

The reply-length rule is what lets the RTU master end a reply the moment its last byte arrives,
instead of waiting for silence (USB adapters deliver bytes in bursts, so silence lies):

| function codes                          | reply length (RTU, with address and CRC) |
|-----------------------------------------|------------------------------------------|
| 01 02 03 04 0C 11 14 15 17              | 5 + byte count (the byte at offset 2)    |
| 05 06 0F 10                             | 8                                        |
| 07                                      | 5                                        |
| 08                                      | same length as the request (echo)        |
| 0B                                      | 8                                        |
| 16                                      | 10                                       |
| any code with the high bit set          | 5 (exception)                            |
| anything else                           | unknown: ends on silence                 |
"""

from __future__ import annotations

from typing import Final

READ_COILS: Final = 0x01
READ_DISCRETE_INPUTS: Final = 0x02
READ_HOLDING_REGISTERS: Final = 0x03
READ_INPUT_REGISTERS: Final = 0x04
WRITE_SINGLE_COIL: Final = 0x05
WRITE_SINGLE_REGISTER: Final = 0x06
READ_EXCEPTION_STATUS: Final = 0x07
DIAGNOSTICS: Final = 0x08
GET_COMM_EVENT_COUNTER: Final = 0x0B
WRITE_MULTIPLE_COILS: Final = 0x0F
WRITE_MULTIPLE_REGISTERS: Final = 0x10
MASK_WRITE_REGISTER: Final = 0x16
READ_WRITE_MULTIPLE_REGISTERS: Final = 0x17

EXCEPTION_BIT: Final = 0x80

# Replies whose length is 5 + the byte count found at offset 2 of the RTU frame.
BYTE_COUNT_REPLIES: Final = frozenset({0x01, 0x02, 0x03, 0x04, 0x0C, 0x11, 0x14, 0x15, 0x17})
# Replies of a fixed RTU length.
FIXED_REPLIES: Final = {0x05: 8, 0x06: 8, 0x0F: 8, 0x10: 8, 0x07: 5, 0x0B: 8, 0x16: 10}

# Reads that change nothing: identical ones waiting in a queue can share one transaction.
PURE_READS: Final = frozenset({0x01, 0x02, 0x03, 0x04})
# Writes: first in the queue, and the only codes a broadcast (address 0) may carry.
WRITES: Final = frozenset({0x05, 0x06, 0x0F, 0x10, 0x16, 0x17})
BROADCAST_WRITES: Final = frozenset({0x05, 0x06, 0x0F, 0x10, 0x16})

# Functions that only read: what `read_only` lets through. 08H only with sub-function 0000
# (return query data): its other sub-functions restart, clear or silence the device.
READ_ONLY_FUNCTIONS: Final = frozenset(
    {0x01, 0x02, 0x03, 0x04, 0x07, 0x0B, 0x0C, 0x11, 0x14, 0x18, 0x2B}
)


def changes_nothing(pdu: bytes) -> bool:
    """True for a request that only reads; an allow-list, so vendor codes count as writes."""
    function = pdu[0]
    if function == DIAGNOSTICS:
        return pdu[1:3] == b"\x00\x00"
    return function in READ_ONLY_FUNCTIONS


NEED_MORE = 0
"""`rtu_reply_length` needs more header bytes before it can tell."""
UNKNOWN_LENGTH = -1
"""`rtu_reply_length` cannot know: the reply ends on silence."""


def rtu_reply_length(header: bytes | bytearray, request_length: int) -> int:
    """Total RTU length of the reply that starts with `header` (address, function, ...).

    Returns NEED_MORE until enough of the header is there (2 bytes, 3 for byte-count replies),
    UNKNOWN_LENGTH for function codes this table doesn't know, else the length in bytes.
    `request_length` is the RTU length of the request, which an 08H reply echoes.
    """
    if len(header) < 2:
        return NEED_MORE
    function = header[1]
    if function & EXCEPTION_BIT:
        return 5
    fixed = FIXED_REPLIES.get(function)
    if fixed is not None:
        return fixed
    if function in BYTE_COUNT_REPLIES:
        return 5 + header[2] if len(header) >= 3 else NEED_MORE
    if function == DIAGNOSTICS:
        return request_length
    return UNKNOWN_LENGTH


def exception_pdu(function: int, code: int) -> bytes:
    """The PDU of an exception response to `function`: function + 80H, then the code."""
    return bytes(((function | EXCEPTION_BIT) & 0xFF, code & 0xFF))


def is_exception(pdu: bytes) -> bool:
    return len(pdu) >= 1 and bool(pdu[0] & EXCEPTION_BIT)
