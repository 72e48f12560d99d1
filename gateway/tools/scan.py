"""Finding the drives on a line: 08H loop-back at each address, then identification.

The loop-back is the cheapest question every INVT drive answers, and any answer (the echo or an
exception) proves a device is there. A silent address costs exactly one short response timeout
and no retry: a full scan of 1-247 at 50 ms takes about 15 s instead of the minutes a poll with
a normal timeout and retries would. Only found addresses get the longer questions: 2100H-2103H
in one read (state word 1, state word 2, fault code, identification code); a drive that refuses
them is asked each other maker's question in turn (`gateway.profile.SCAN_QUESTIONS`: an ABB
drive's 40001-40004).
"""

from __future__ import annotations

import contextlib
import struct
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

from gateway.errors import BadReply, ReplyTimeout
from gateway.modbus.functions import DIAGNOSTICS, READ_HOLDING_REGISTERS, is_exception
from gateway.profile import (
    SCAN_QUESTIONS,
    Identified,
    InvtProfile,
    Question,
    profiles_for_identification,
    words,
)
from gateway.profile.faults import GD350_FAULTS, FaultTable
from gateway.profile.invt import STATE_WORD_1
from gateway.tools.masters import Master

LOOP_BACK = struct.pack(">BHH", DIAGNOSTICS, 0x0000, 0xA55A)
"""Sub-function 0000 (return query data) with a pattern that shows bit errors."""
STATUS_WORDS = 4
"""2100H state word 1, 2101H state word 2, 2102H fault code, 2103H identification."""
IDENTIFY_ATTEMPTS = 2


@dataclass(frozen=True)
class FoundDrive:
    address: int
    identification: int | None = None
    state_word_1: int | None = None
    state_word_2: int | None = None
    fault: int | None = None
    note: str = ""
    identified: Identified | None = None
    """What another maker's question found (a drive that refused 2100H-2103H)."""

    @property
    def model(self) -> str:
        if self.identified is not None:
            return self.identified.model
        if self.identification is None:
            return "unknown"
        return words.identification(self.identification)

    @property
    def profile(self) -> InvtProfile | None:
        """The one series the code places; None for none or two (010AH: GD300 or GD300-LIFT)."""
        if self.identification is None:
            return None
        profiles = profiles_for_identification(self.identification)
        return profiles[0] if len(profiles) == 1 else None

    @property
    def state(self) -> str:
        if self.identified is not None:
            return self.identified.state
        return "-" if self.state_word_1 is None else words.state_word_1(self.state_word_1)

    @property
    def command_source(self) -> str:
        if self.identified is not None:
            return self.identified.command_source
        if self.state_word_2 is None:
            return "-"
        return words.state_word_2(self.profile, self.state_word_2).command_source

    @property
    def fault_text(self) -> str:
        if self.identified is not None:
            return self.identified.fault
        if self.fault is None:
            return "-"
        if self.profile is not None:
            return words.fault(self.profile, self.fault).description
        return self.fault_table.describe(self.fault)

    @property
    def fault_table(self) -> FaultTable:
        """The series' own table where the code places it (GD300 and GD300-LIFT list the same
        codes); the widest table for a drive no profile places."""
        profiles = (
            () if self.identification is None else profiles_for_identification(self.identification)
        )
        tables = {tuple(profile.faults.entries.items()) for profile in profiles}
        return profiles[0].faults if len(tables) == 1 else GD350_FAULTS


@dataclass
class ScanResult:
    found: list[FoundDrive] = field(default_factory=list)
    garbled: list[int] = field(default_factory=list)
    """Addresses where bytes came back that were no valid frame: a hint of wrong settings."""


Progress = Callable[[int, FoundDrive | None], None]


def scan(master: Master, addresses: Iterable[int], progress: Progress | None = None) -> ScanResult:
    result = ScanResult()
    addresses = list(addresses)
    if addresses:
        learn_the_adapter(master, addresses[0])
    for address in addresses:
        found = probe(master, address, result)
        if found is not None:
            result.found.append(found)
        if progress is not None:
            progress(address, found)
    return result


def learn_the_adapter(master: Master, address: int) -> None:
    """One read before the loop-backs, so an echoing adapter shows itself.

    A loop-back's reply is a copy of the request, and so is an adapter's echo of it: the line
    can tell them apart only once it has seen the adapter echo a request whose reply differs
    (a read), or by wire timing on a real port. Without this, every silent address of a scan
    through an echoing adapter on a virtual line would look like a drive.
    """
    pdu = struct.pack(">BHH", READ_HOLDING_REGISTERS, STATE_WORD_1, 1)
    with contextlib.suppress(ReplyTimeout, BadReply):
        master.request(address, pdu)


def probe(master: Master, address: int, result: ScanResult) -> FoundDrive | None:
    try:
        reply = master.request(address, LOOP_BACK)
    except ReplyTimeout:
        return None
    except BadReply:
        result.garbled.append(address)
        return None
    note = ""
    if is_exception(reply):
        note = f"loop-back refused with exception {reply[1]:02X}H"
    elif reply != LOOP_BACK:
        note = f"loop-back echo differs: {reply.hex(' ')}"
    return identify(master, address, note)


def identify(master: Master, address: int, note: str) -> FoundDrive:
    pdu = struct.pack(">BHH", READ_HOLDING_REGISTERS, STATE_WORD_1, STATUS_WORDS)
    for _ in range(IDENTIFY_ATTEMPTS):
        try:
            reply = master.request(address, pdu)
        except (ReplyTimeout, BadReply):
            continue
        if is_exception(reply):
            for question in SCAN_QUESTIONS:
                identified = ask(master, address, question)
                if identified is not None:
                    return FoundDrive(address, note=note, identified=identified)
            code = reply[1] if len(reply) > 1 else 0
            refused = f"2100H-2103H refused with exception {code:02X}H: not an INVT drive?"
            return FoundDrive(address, note=_join(note, refused))
        if len(reply) == 2 + 2 * STATUS_WORDS:
            state_1, state_2, fault, identification = struct.unpack(">4H", reply[2:])
            return FoundDrive(address, identification, state_1, state_2, fault, note)
    return FoundDrive(address, note=_join(note, "no answer to the identification read"))


def ask(master: Master, address: int, question: Question) -> Identified | None:
    """A maker's identification read; None when the drive refuses it or it says "not mine"."""
    pdu = struct.pack(">BHH", READ_HOLDING_REGISTERS, question.start, question.count)
    for _ in range(IDENTIFY_ATTEMPTS):
        try:
            reply = master.request(address, pdu)
        except (ReplyTimeout, BadReply):
            continue
        if is_exception(reply) or len(reply) != 2 + 2 * question.count:
            return None
        return question.answer(struct.unpack(f">{question.count}H", reply[2:]))
    return None


def _join(*notes: str) -> str:
    return "; ".join(note for note in notes if note)
