"""What each drive on a line may still answer, and how the bus gets back in step with it.

RTU frames carry no transaction id, and a line guarantees only this:

1. a drive answers its own requests in the order they came, each at most once (some never: a
   request lost to noise, dropped by a busy drive, or cut short by a stall);
2. a reply carries the drive's address, the request's function and a length and content that
   follow from the request, and nothing else: two requests of the same function and length to
   one drive have replies that look alike.

So the bus keeps, per drive, every request that went out and whose reply it did not take: it
timed out, its attempt ended on a corrupt frame, noise or a reply it could not trust. The drive
*owes* those. From 1 and 2:

- **A frame is the answer to the request in flight only if its drive owed nothing when the
  request went out, and nothing else came from that drive first.** Then the next frame it sends
  answers this very request (1). Every other whole, sound frame is set aside, never handed to a
  client, and does not end the attempt: the asked drive's reply may still come.
- A frame set aside from a drive that owes answers the earliest owed request it can answer (2).
  By 1, every request owed before that one has been answered or never will be: they are taken
  off with it. A drive whose last owed request is answered so is in step again.
- A frame that answers nothing the drive owes (another master, a drive out of step) leaves the
  drive *unsure*: nothing from it is trusted until it is in step again.
- Before anything else goes to a drive that owes or is unsure, the bus sends a **marker**: a
  request whose replies (normal or exception) no owed request's reply can look like (2). Frames
  before the marker's answer are set aside as above; once its answer is back, nothing older is in
  flight (1) and the drive is in step. One exception: a retry, when all the drive owes is that
  very request sent before for the same transaction, needs none: whichever send a reply answers,
  it answers the question its client is waiting on; what was owed stays owed, so the next
  transaction gets its marker (never a reply one request behind).

A marker never depends on an optional function code. It is a read the drive has answered before
or been asked before, changed so that its reply is told from every owed one (the other read
function, 04H for 03H; fewer registers; a written register read back), the next in turn when one
gets no answer. The diagnostic echo (08H 0000, a fresh value each time) is the marker only when
no such read can be made, or for a drive that has answered an echo before, when a read went
unanswered. Reads come first because an echo is not harmless to a device that doesn't know 08H:
libmodbus takes it for a short frame with a wrong CRC, and may take the frames after it for the
rest of that one until its line has been silent for half a second. A drive seen answering a read
but never an echo sent before it is remembered as one (`no_echo`, said once in the log).
Offline probes are markers too.

One assumption is added, for liveness only: a reply later than `LATE_HORIZON_S` does not come.
An owed request that old no longer narrows the choice of marker (it stays owed as "unsure"): a
device whose every other marker collides with it can still be brought back.
"""

from __future__ import annotations

import logging
import time
from typing import NamedTuple

from gateway.errors import BadReply
from gateway.modbus.functions import (
    DIAGNOSTICS,
    EXCEPTION_BIT,
    READ_HOLDING_REGISTERS,
    READ_INPUT_REGISTERS,
    WRITE_MULTIPLE_REGISTERS,
    WRITE_SINGLE_REGISTER,
)
from gateway.modbus.rtu import build_frame, check_reply

log = logging.getLogger(__name__)


class Owed(NamedTuple):
    """A request whose reply was not taken, and may still come."""

    frame: bytes
    sent_at: float
    """When it went out (`time.monotonic()`)."""
    by: object
    """The transaction that sent it (a retry within it needs no marker: `needs_marker`)."""
    timeout_s: float
    """The response timeout it had: what its reply came later than."""


LOOP_BACK = b"\x00\x00"
"""08H sub-function 0000, return query data: the reply repeats the request."""
LATE_HORIZON_S = 10.0
"""An owed request older than this no longer narrows the choice of marker (module docstring)."""
MAX_OWED = 64
"""Requests kept owed per drive at most (a bound on memory for a drive that never answers);
past it the oldest go and the drive stays unsure."""
_READS = (READ_HOLDING_REGISTERS, READ_INPUT_REGISTERS)
ILLEGAL_FUNCTION = 0x01
"""The exception code of a function the device doesn't serve (an illegal address is not that)."""


def is_reply_to(request: bytes, frame: bytes) -> bool:
    """Could the whole, CRC-checked `frame` be the reply to the RTU `request`, by rule 2?

    An 08H echo's normal reply is the request byte for byte (its value included); an exception
    answers any request of its function.
    """
    try:
        pdu = check_reply(request, frame, crc_checked=True)
    except BadReply:
        return False
    return request[1] != DIAGNOSTICS or frame == request or bool(pdu[0] & EXCEPTION_BIT)


def _read(function: int, start: int, count: int) -> bytes:
    return bytes((function,)) + start.to_bytes(2) + count.to_bytes(2)


def _reads_from(request: bytes) -> list[bytes]:
    """Reads (PDUs) a device asked `request` most likely answers, each with a reply that looks
    unlike the reply to `request` (a written register read back; a read as the other read
    function, or of fewer registers)."""
    if len(request) < 8:
        return []
    function, start, count = request[1], int.from_bytes(request[2:4]), int.from_bytes(request[4:6])
    if function in _READS and 0 < count <= 125:
        other = _READS[function == READ_HOLDING_REGISTERS]  # 03H for 04H, 04H for 03H
        reads = [_read(other, start, count)]
        for fewer in range(count - 1, 0, -1):  # a part of what was read: as readable
            reads += [_read(function, start, fewer), _read(other, start, fewer)]
        for more in range(count + 1, min(count + 3, 126)):  # the registers after, last
            reads += [_read(function, start, more), _read(other, start, more)]
        return reads
    if function == WRITE_SINGLE_REGISTER:
        return [_read(READ_HOLDING_REGISTERS, start, 1), _read(READ_INPUT_REGISTERS, start, 1)]
    if function == WRITE_MULTIPLE_REGISTERS and 0 < count <= 123:
        return [_read(READ_HOLDING_REGISTERS, start, count), _read(READ_INPUT_REGISTERS, start, 1)]
    return []


def _collides(marker_pdu: bytes, owed: bytes) -> bool:
    """Could a normal reply to the read `marker_pdu` look like the reply to the `owed` request?"""
    if owed[1] != marker_pdu[0]:
        return False
    return len(owed) < 8 or owed[4:6] == marker_pdu[3:5]  # same function, same count


class LateReplies:
    """One bus's ledger: what each drive owes, and the marker that brings it back in step."""

    def __init__(self, bus: str) -> None:
        self.bus = bus
        self.owing: dict[int, list[Owed]] = {}
        """Address → the requests it owes replies to, oldest first. A drive that is here must
        get a marker before anything else (also with an empty list: unsure), but for a retry
        (`needs_marker`)."""
        self.unsure: set[int] = set()
        """Drives that sent a frame answering nothing they owed (module docstring)."""
        self.answered: dict[int, bytes] = {}
        """Address → the last request frame it answered: what a marker may be made from."""
        self.refused: dict[int, set[int]] = {}
        """Address → read functions it answered with exception 01H, illegal function (INVT
        drives: 04H): their markers come last, and none while one of its requests is owed."""
        self.no_echo: set[int] = set()
        """Drives learnt not to answer 08H: resynchronised with reads only."""
        self._echo_missed: set[int] = set()
        """Drives whose last echo marker got no answer."""
        self._echo_ok: set[int] = set()
        """Drives that have answered an echo: it may be their marker when reads go unanswered."""
        self._read_missed_last: set[int] = set()
        """Drives whose last marker was a read that got no answer: the echo is tried next."""
        self._turn: dict[int, int] = {}
        """Address → which of its marker reads comes next (one more after each missed)."""
        self._value = 0
        self._told: set[int] = set()

    def owes(self, address: int) -> bool:
        return address in self.owing

    def needs_marker(self, address: int, frame: bytes, by: object) -> bool:
        """Must a marker go before `frame` to `address`, sent for the transaction `by`? Not
        when it owes nothing, nor when all it owes is this very request sent before for this
        same transaction (a retry after a timeout or a corrupt reply): whichever send a reply
        answers, it answers the question its client is waiting on. What it owed stays owed
        (the reply taken may be the earlier send's), so the next transaction gets a marker."""
        owed = self.owing.get(address)
        if owed is None:
            return False
        if not owed or address in self.unsure:
            return True
        return any(owed.frame != frame or owed.by is not by for owed in owed)

    def owed_frames(self, address: int) -> tuple[bytes, ...]:
        return tuple(owed.frame for owed in self.owing.get(address, ()))

    def unanswered(
        self, address: int, frame: bytes, sent_at: float, by: object = None, timeout_s: float = 0.0
    ) -> None:
        """`frame` went to `address` for the transaction `by` (which gave it `timeout_s`) and
        its reply was not taken: it may still come. Requests owed longer than `LATE_HORIZON_S`
        are let go (a dead drive's probes would pile up for good otherwise); the drive stays
        unsure, in want of a marker."""
        owed = self.owing.setdefault(address, [])
        owed.append(Owed(frame, sent_at, by, timeout_s))
        if sent_at - owed[0].sent_at > LATE_HORIZON_S or len(owed) > MAX_OWED:
            kept = [entry for entry in owed if sent_at - entry.sent_at <= LATE_HORIZON_S]
            owed[:] = kept[-MAX_OWED:]
            self.unsure.add(address)

    def broadcast(self) -> None:
        """A broadcast went out (a write to every drive): a reply owed from before it carries
        values from before it, so no drive that owes may skip its marker now."""
        self.unsure.update(self.owing)

    def heard(self, frame: bytes) -> Owed | None:
        """A whole, sound frame set aside: take off what it answers (rule 1); the request it
        answers. None when it answers nothing its drive owed: that drive is unsure from now."""
        address = frame[0]
        if frame[1] & EXCEPTION_BIT and frame[1] & 0x7F in _READS and frame[2] == ILLEGAL_FUNCTION:
            self.refused.setdefault(address, set()).add(frame[1] & 0x7F)
        owed = self.owing.get(address)
        if owed:
            for index, entry in enumerate(owed):
                request = entry.frame
                if is_reply_to(request, frame):
                    skipped = owed[:index]
                    del owed[: index + 1]
                    if request[1] == DIAGNOSTICS:
                        self._echo_answered(address)
                    elif any(earlier.frame[1] == DIAGNOSTICS for earlier in skipped):
                        self._no_echo(address)  # answered a later read, never the echo
                    if not owed and address not in self.unsure:
                        del self.owing[address]  # its last owed reply came: in step
                    return entry
        self.owing.setdefault(address, [])
        self.unsure.add(address)
        return None

    def marker(self, address: int) -> bytes:
        """The marker to send to `address` now (module docstring): its frame.

        A read when one can be made, the next in turn after each one missed; the echo only when
        none can, or, for a drive that has answered an echo before, after a read went
        unanswered. Reads first: a device that frames only what it knows takes an echo for a
        broken frame, and may take the frames after it for the rest of that one (libmodbus
        does, until its line has been silent for half a second).
        """
        owed = self.owing.get(address, [])
        now = time.monotonic()
        recent = [entry.frame for entry in owed if now - entry.sent_at < LATE_HORIZON_S]
        reads = self._marker_reads(address, recent)
        echo_next = address in self._echo_ok and address in self._read_missed_last
        if reads and not echo_next:
            chosen = reads[self._turn.get(address, 0) % len(reads)]
        else:
            self._value = self._value % 0xFFFF + 1
            chosen = bytes((DIAGNOSTICS,)) + LOOP_BACK + self._value.to_bytes(2)
        return build_frame(address, chosen)

    def _marker_reads(self, address: int, owed: list[bytes]) -> list[bytes]:
        functions = {request[1] for request in owed}
        refused = self.refused.get(address, ())
        sources = list(owed)
        last = self.answered.get(address)
        if last is not None:
            sources.append(last)
        reads: list[bytes] = []
        for source in reversed(sources):  # the most recent first: the likeliest to be answered
            for pdu in _reads_from(source):
                if pdu in reads or any(_collides(pdu, request) for request in owed):
                    continue
                if pdu[0] in refused and pdu[0] in functions:
                    continue  # its exception would look like an owed request's
                reads.append(pdu)
        # A read of a function nothing owed has first: even an exception to it is unambiguous;
        # a function the drive refuses last.
        reads.sort(key=lambda pdu: (pdu[0] in refused, pdu[0] in functions))
        return reads

    def marker_missed(self, address: int, marker: bytes) -> None:
        """The marker got no answer it could trust: the next one is of the other kind (or the
        next read in turn)."""
        if marker[1] == DIAGNOSTICS:
            self._echo_missed.add(address)
            self._read_missed_last.discard(address)
        else:
            self._turn[address] = self._turn.get(address, 0) + 1
            self._read_missed_last.add(address)

    def caught_up(self, address: int, marker: bytes, answer: bytes = b"") -> None:
        """The marker's answer (`answer`, its PDU) came: nothing older is in flight from
        `address`."""
        if answer[1:2] == bytes((ILLEGAL_FUNCTION,)) and answer[0] & EXCEPTION_BIT:
            self.refused.setdefault(address, set()).add(marker[1])
        self.owing.pop(address, None)
        self.unsure.discard(address)
        self._read_missed_last.discard(address)
        if marker[1] == DIAGNOSTICS:
            self._echo_answered(address)
        elif address in self._echo_missed:
            self._no_echo(address)

    def _no_echo(self, address: int) -> None:
        """`address` answers reads, but an echo sent before went unanswered."""
        self._echo_missed.add(address)
        if address in self.no_echo:
            return
        self.no_echo.add(address)
        log.warning(
            "bus %s: drive %d answers reads but not the diagnostic echo (08H): it is "
            "resynchronised and probed with reads from now",
            self.bus,
            address,
        )

    def _echo_answered(self, address: int) -> None:
        self._echo_missed.discard(address)
        self.no_echo.discard(address)
        self._echo_ok.add(address)

    def seen(self, address: int, late_at: float, answered: Owed) -> None:
        """A reply from `address` to the request `answered` was set aside as late (at
        `late_at`): say once what it suggests, with the timeout that request had."""
        if address in self._told:
            return
        self._told.add(address)
        after = f" about {(late_at - answered.sent_at) * 1000:.0f} ms after its request,"
        timeout_s = answered.timeout_s
        log.warning(
            "bus %s: drive %d answered%s later than timeout_ms (%.0f): its replies were set "
            "aside, never taken for another request's (counted in "
            "invt_gateway_drive_late_replies_total). Set timeout_ms above the drive's delay "
            "(its P14.03 response delay, EEPROM writes, a serial device server's link)",
            self.bus,
            address,
            after,
            timeout_s * 1000,
        )
