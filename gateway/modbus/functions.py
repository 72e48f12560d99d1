"""Function codes as data: one registry row per code the gateway knows, one path for the rest.

Each row says how a request must look (`request_checks`), how long its reply is and whether a
reply fits it (`replies`), and what the gateway may do with it:

| code | name                         | reply length (RTU)       | write | bcast | coal. | split |
|------|------------------------------|--------------------------|-------|-------|-------|-------|
| 01H  | read coils                   | 5 + byte count           |       |       | yes   |       |
| 02H  | read discrete inputs         | 5 + byte count           |       |       | yes   |       |
| 03H  | read holding registers       | 5 + byte count           |       |       | yes   | yes   |
| 04H  | read input registers         | 5 + byte count           |       |       | yes   | yes   |
| 05H  | write single coil            | 8                        | yes   | yes   |       |       |
| 06H  | write single register        | 8                        | yes   | yes   |       |       |
| 07H  | read exception status        | 5                        |       |       |       |       |
| 08H  | diagnostics                  | the request's (echo)     |       |       |       |       |
| 0BH  | get comm event counter       | 8                        |       |       |       |       |
| 0CH  | get comm event log           | 5 + byte count           |       |       |       |       |
| 0FH  | write multiple coils         | 8                        | yes   | yes   |       |       |
| 10H  | write multiple registers     | 8                        | yes   | yes   |       | yes   |
| 11H  | report server id             | 5 + byte count           |       |       |       |       |
| 14H  | read file record             | 5 + byte count           |       |       |       |       |
| 15H  | write file record            | 5 + byte count           | yes   |       |       |       |
| 16H  | mask write register          | 10                       | yes   | yes   |       |       |
| 17H  | read/write multiple regs.    | 5 + byte count           | yes   |       |       |       |
| 18H  | read FIFO queue              | 6 + two-byte count       |       |       |       |       |
| 2BH  | encapsulated interface       | 0EH: parsed from objects |       |       |       |       |
| any  | exception (function + 80H)   | 5                        |       |       |       |       |
| else | unknown (a vendor's code)    | ends on silence          |       |       |       |       |

- write: goes first in the bus's queue, and makes the poll cache of its drive stale.
- bcast: may go to unit id 0 as a broadcast (every drive acts, none answers); not 17H, which
  also reads.
- coal(esce): a pure read; identical ones waiting in a queue share one transaction, and one whose
  client has gone is not sent.
- split: a request over a drive's word limit becomes several (`splitting`).
- `changes_nothing` (what `modbus_tcp.read_only` lets through): every read above, and 08H only
  with sub-function 0000H (return query data): its others restart, clear or silence the device.
  An allow-list: an unknown code counts as a write there.
- `registers`: the registers a request reads or writes (03H 04H 06H 10H 16H 17H; `registers`),
  for the access rules that name registers.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from functools import lru_cache
from types import MappingProxyType
from typing import Final

from gateway.modbus import registers, replies
from gateway.modbus import request_checks as checks
from gateway.modbus.registers import RegistersTouched
from gateway.modbus.replies import (
    EXCEPTION_REPLY,
    NEED_MORE,
    UNKNOWN_LENGTH,
    ReplyFits,
    ReplyLength,
)
from gateway.modbus.request_checks import (
    MAX_READ_BITS,
    MAX_READ_REGISTERS,
    MAX_WRITE_BITS,
    MAX_WRITE_REGISTERS,
    Malformed,
    Reason,
    RequestCheck,
)
from gateway.modbus.splitting import REGISTER_READ, REGISTER_WRITE, Split

__all__ = [
    "DIAGNOSTICS",
    "ENCAPSULATED_INTERFACE",
    "EXCEPTION_BIT",
    "FUNCTIONS",
    "GET_COMM_EVENT_COUNTER",
    "GET_COMM_EVENT_LOG",
    "LOOP_BACK",
    "MASK_WRITE_REGISTER",
    "MAX_READ_BITS",
    "MAX_READ_REGISTERS",
    "MAX_WRITE_BITS",
    "MAX_WRITE_REGISTERS",
    "NEED_MORE",
    "READ_COILS",
    "READ_DISCRETE_INPUTS",
    "READ_EXCEPTION_STATUS",
    "READ_FIFO_QUEUE",
    "READ_FILE_RECORD",
    "READ_HOLDING_REGISTERS",
    "READ_INPUT_REGISTERS",
    "READ_WRITE_MULTIPLE_REGISTERS",
    "REPORT_SERVER_ID",
    "UNKNOWN_FUNCTION",
    "UNKNOWN_LENGTH",
    "WRITE_FILE_RECORD",
    "WRITE_MULTIPLE_COILS",
    "WRITE_MULTIPLE_REGISTERS",
    "WRITE_SINGLE_COIL",
    "WRITE_SINGLE_REGISTER",
    "Function",
    "Malformed",
    "Reason",
    "changes_nothing",
    "check_request",
    "exception_pdu",
    "is_exception",
    "join_replies",
    "known_function",
    "lookup",
    "rtu_reply_length",
    "split_request",
]

READ_COILS: Final = 0x01
READ_DISCRETE_INPUTS: Final = 0x02
READ_HOLDING_REGISTERS: Final = 0x03
READ_INPUT_REGISTERS: Final = 0x04
WRITE_SINGLE_COIL: Final = 0x05
WRITE_SINGLE_REGISTER: Final = 0x06
READ_EXCEPTION_STATUS: Final = 0x07
DIAGNOSTICS: Final = 0x08
GET_COMM_EVENT_COUNTER: Final = 0x0B
GET_COMM_EVENT_LOG: Final = 0x0C
WRITE_MULTIPLE_COILS: Final = 0x0F
WRITE_MULTIPLE_REGISTERS: Final = 0x10
REPORT_SERVER_ID: Final = 0x11
READ_FILE_RECORD: Final = 0x14
WRITE_FILE_RECORD: Final = 0x15
MASK_WRITE_REGISTER: Final = 0x16
READ_WRITE_MULTIPLE_REGISTERS: Final = 0x17
READ_FIFO_QUEUE: Final = 0x18
ENCAPSULATED_INTERFACE: Final = 0x2B

EXCEPTION_BIT: Final = 0x80
LOOP_BACK: Final = b"\x00\x00"
"""08H sub-function 0000H, return query data: the only diagnostic that changes nothing."""


def _always(pdu: bytes) -> bool:
    return True


def _never(pdu: bytes) -> bool:
    return False


def _loop_back_only(pdu: bytes) -> bool:
    return pdu[1:3] == LOOP_BACK


@dataclass(frozen=True, slots=True)
class Function:
    """What the gateway knows of one function code."""

    name: str
    check: RequestCheck
    reply_length: ReplyLength
    fits: ReplyFits = replies.always
    writes: bool = False
    broadcastable: bool = False
    coalescable: bool = False
    split: Split | None = None
    changes_nothing: Callable[[bytes], bool] = _always
    registers: RegistersTouched = registers.none
    """The registers it reads or writes, for `modbus_tcp.access` rules that name registers."""


FUNCTIONS: Final[Mapping[int, Function]] = MappingProxyType(
    {
        READ_COILS: Function(
            "read coils",
            checks.block_read(MAX_READ_BITS),
            replies.byte_count,
            replies.bits_counted,
            coalescable=True,
        ),
        READ_DISCRETE_INPUTS: Function(
            "read discrete inputs",
            checks.block_read(MAX_READ_BITS),
            replies.byte_count,
            replies.bits_counted,
            coalescable=True,
        ),
        READ_HOLDING_REGISTERS: Function(
            "read holding registers",
            checks.block_read(MAX_READ_REGISTERS),
            replies.byte_count,
            replies.words_counted,
            coalescable=True,
            split=REGISTER_READ,
            registers=registers.block,
        ),
        READ_INPUT_REGISTERS: Function(
            "read input registers",
            checks.block_read(MAX_READ_REGISTERS),
            replies.byte_count,
            replies.words_counted,
            coalescable=True,
            split=REGISTER_READ,
            registers=registers.block,
        ),
        WRITE_SINGLE_COIL: Function(
            "write single coil",
            checks.write_single_coil,
            replies.fixed(8),
            replies.echoed(5),
            writes=True,
            broadcastable=True,
            changes_nothing=_never,
        ),
        WRITE_SINGLE_REGISTER: Function(
            "write single register",
            checks.exactly(5),
            replies.fixed(8),
            replies.echoed(5),
            writes=True,
            broadcastable=True,
            changes_nothing=_never,
            registers=registers.single,
        ),
        READ_EXCEPTION_STATUS: Function(
            "read exception status", checks.exactly(1), replies.fixed(5)
        ),
        DIAGNOSTICS: Function(
            "diagnostics", checks.diagnostics, replies.echo, changes_nothing=_loop_back_only
        ),
        GET_COMM_EVENT_COUNTER: Function(
            "get comm event counter", checks.exactly(1), replies.fixed(8)
        ),
        GET_COMM_EVENT_LOG: Function("get comm event log", checks.exactly(1), replies.byte_count),
        WRITE_MULTIPLE_COILS: Function(
            "write multiple coils",
            checks.block_write(MAX_WRITE_BITS, checks.bits),
            replies.fixed(8),
            replies.start_and_quantity_echoed,
            writes=True,
            broadcastable=True,
            changes_nothing=_never,
        ),
        WRITE_MULTIPLE_REGISTERS: Function(
            "write multiple registers",
            checks.block_write(MAX_WRITE_REGISTERS, checks.words),
            replies.fixed(8),
            replies.start_and_quantity_echoed,
            writes=True,
            broadcastable=True,
            split=REGISTER_WRITE,
            changes_nothing=_never,
            registers=registers.block,
        ),
        REPORT_SERVER_ID: Function("report server id", checks.exactly(1), replies.byte_count),
        READ_FILE_RECORD: Function(
            "read file record",
            checks.file_records(7, 245, checks.FILE_SUB_REQUEST),
            replies.byte_count,
        ),
        WRITE_FILE_RECORD: Function(
            "write file record",
            checks.file_records(9, 251),
            replies.byte_count,
            writes=True,
            changes_nothing=_never,
        ),
        MASK_WRITE_REGISTER: Function(
            "mask write register",
            checks.exactly(7),
            replies.fixed(10),
            replies.echoed(7),
            writes=True,
            broadcastable=True,
            changes_nothing=_never,
            registers=registers.single,
        ),
        READ_WRITE_MULTIPLE_REGISTERS: Function(
            "read/write multiple registers",
            checks.read_write_registers,
            replies.byte_count,
            replies.read_words_counted,
            writes=True,
            changes_nothing=_never,
            registers=registers.read_and_write,
        ),
        READ_FIFO_QUEUE: Function("read FIFO queue", checks.exactly(3), replies.two_byte_count),
        ENCAPSULATED_INTERFACE: Function(
            "encapsulated interface",
            checks.encapsulated_interface,
            replies.device_identification,
        ),
    }
)

UNKNOWN_FUNCTION: Final = Function(
    "unknown function", checks.any_function, replies.unknown, changes_nothing=_never
)
"""The one path for codes the registry doesn't know: passed on as they are, ended on silence."""


_BY_CODE: Final[dict[int, Function]] = dict(FUNCTIONS)
"""`FUNCTIONS` as a plain dict: looked up several times per transaction, and a read-only
proxy's `get` goes through the proxy first."""


def lookup(code: int) -> Function:
    return _BY_CODE.get(code, UNKNOWN_FUNCTION)


known_function = _BY_CODE.get
"""`lookup` without a Python frame (the dict's own `get`), for a caller once per request:
None for a code the registry doesn't know (`lookup`'s `UNKNOWN_FUNCTION` then)."""


@lru_cache(maxsize=1024)
def check_request(pdu: bytes) -> Malformed | None:
    """None for a well-formed request PDU; else why not, and so which exception it earns.
    Remembered (a pure function of the bytes): clients repeat their requests, and a hit is a
    hash lookup in C where the checks are several Python calls."""
    return checks.function_code(pdu) or lookup(pdu[0]).check(pdu)


@lru_cache(maxsize=1024)
def changes_nothing(pdu: bytes) -> bool:
    """True for a request that only reads; an allow-list, so vendor codes count as writes.
    Remembered, as `check_request` is."""
    return lookup(pdu[0]).changes_nothing(pdu)


@lru_cache(maxsize=1024)
def front_door(pdu: bytes) -> tuple[bool, Malformed | None]:
    """(`changes_nothing`, `check_request`) of a client's request in one lookup: the Modbus-TCP
    server asks both of every request it takes, and each remembered answer costs a hash
    lookup through the cache's wrapper (some 700 instructions a call, callgrind)."""
    return changes_nothing(pdu), check_request(pdu)


def rtu_reply_length(header: bytes | bytearray, request_length: int) -> int:
    """Total RTU length of the reply that starts with `header` (address, function, ...).

    NEED_MORE until enough of the header is there (2 bytes, 3 for byte-count replies),
    UNKNOWN_LENGTH for function codes the registry can't size, else the length in bytes: read up
    to it and ask again, as it may be a step for replies with several length fields (18H,
    2BH/0EH); once that many bytes are there it is the reply's length (see `replies`).
    `request_length` is the RTU length of the request, which an 08H reply echoes.
    """
    if len(header) < 2:
        return NEED_MORE
    function = header[1]
    if function & EXCEPTION_BIT:
        return EXCEPTION_REPLY
    return lookup(function).reply_length(header, request_length)


def split_request(pdu: bytes, max_words: int, *, checked: bool = False) -> list[bytes] | None:
    """The parts of a well-formed request over `max_words` words, or None: send it as it is.
    `checked`: `check_request` has passed it already (the front door), no need to again."""
    split = lookup(pdu[0]).split
    if split is None or (not checked and check_request(pdu) is not None):
        return None
    return split.parts(pdu, max_words)


@lru_cache(maxsize=1024)
def needs_split(pdu: bytes, max_words: int) -> bool:
    """Does the request `pdu`, which has passed `check_request`, go out in parts for a drive
    taking at most `max_words` words? Remembered: asked of every read a client sends."""
    return split_request(pdu, max_words, checked=True) is not None


def join_replies(pdu: bytes, parts: Sequence[bytes]) -> bytes:
    """The reply to `pdu` made of its parts' normal replies, in order."""
    split = lookup(pdu[0]).split
    assert split is not None, f"{pdu[0]:02X}H is not split"
    return split.join(pdu, parts)


def exception_pdu(function: int, code: int) -> bytes:
    """The PDU of an exception response to `function`: function + 80H, then the code."""
    return bytes(((function | EXCEPTION_BIT) & 0xFF, code & 0xFF))


def is_exception(pdu: bytes) -> bool:
    return len(pdu) >= 1 and bool(pdu[0] & EXCEPTION_BIT)
