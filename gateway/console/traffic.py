"""The traffic monitor: every attempt on a bus's wire, recorded at all times.

The console sets each bus's `tap` at start (`record_always`): the last `RING_SIZE` attempts per
bus are always kept, so what happened before a trip is there when someone opens the monitor.
The tap only appends a small record (the request, the reply, four times) to that bounded ring
and hands it to each watcher's bounded queue: a few microseconds of the bus's time, some 200
bytes a record (about 0.4 MB per bus). Decoding it into words (`gateway.console.decode`) and
splitting its time happen later, in the reader's own coroutine, never on the bus's time.

Each attempt's time, split (`timing`):
    queue_ms       waiting in the bus's queue before its first attempt (0 for a retry)
    wire_ms        the request's and the reply's bytes on the wire at the line's baud rate
    turnaround_ms  the drive's own answer delay: the line busy with the exchange, less the bytes
    latency_ms     the attempt from its start (the gap before it included) to its end
"""

from __future__ import annotations

import asyncio
import itertools
import logging
import time
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from gateway.bus import Bus
from gateway.bus.line import Exchange
from gateway.bus.queue import Transaction
from gateway.console.decode import describe, exceptions_of
from gateway.errors import BadReply, LineError, PortError, ReplyTimeout
from gateway.modbus.rtu import build_frame
from gateway.poller.drive_state import iso_time
from gateway.profile import DriveProfile

log = logging.getLogger(__name__)

RING_SIZE = 2000
WATCHER_QUEUE = 1000
"""Records a slow watcher may be behind; beyond it they are dropped for that watcher (counted)."""


@dataclass(frozen=True, slots=True)
class DriveLabel:
    name: str
    unit_id: int
    profile: DriveProfile
    """The drive's profile with its site corrections: the monitor decodes with it."""


@dataclass(frozen=True, slots=True)
class Record:
    """One attempt: what the tap saw, undecoded."""

    seq: int
    at: float
    """Wall clock (epoch seconds) when the attempt ended."""
    bus: str
    client: str
    address: int
    pdu: bytes
    attempt: int
    latency_s: float
    outcome: str
    """ok, broadcast, exception, timeout, port_lost, or the bad reply's kind (crc, truncated...)."""
    reply: bytes | None
    """The reply PDU when one passed its CRC; for a bad reply, the bytes that came."""
    queue_s: float = 0.0
    """In the bus's queue before the first attempt (0.0 for a retry)."""
    busy_s: float | None = None
    """The line busy with the exchange (request, the drive's delay, reply); None: no reply."""


@dataclass(slots=True)
class Watcher:
    bus: str
    queue: asyncio.Queue[Record | None] = field(
        default_factory=lambda: asyncio.Queue(WATCHER_QUEUE)
    )
    """None at the end: the console is stopping."""
    dropped: int = 0


class TrafficMonitor:
    def __init__(self, buses: Mapping[str, Bus], drives: Mapping[tuple[str, int], DriveLabel]):
        self.buses = buses
        self.drives = drives
        self.rings: dict[str, deque[Record]] = {name: deque(maxlen=RING_SIZE) for name in buses}
        self._watchers: dict[str, list[Watcher]] = {name: [] for name in buses}
        self._seq = itertools.count(1)
        self.recorded = 0

    def record_always(self) -> None:
        """Keep the last `RING_SIZE` attempts of every bus from now on (a bus reopened by a
        reload keeps its tap: `Application._replace_buses`)."""
        for bus in self.buses.values():
            bus.tap = self._tap

    def watching(self, bus: str) -> bool:
        return bool(self._watchers[bus])

    def watch(self, bus: str) -> Watcher:
        """Start watching `bus` (KeyError for an unknown one); `leave` when done."""
        watchers = self._watchers[bus]
        watcher = Watcher(bus)
        watchers.append(watcher)
        return watcher

    def leave(self, watcher: Watcher) -> None:
        watchers = self._watchers[watcher.bus]
        if watcher in watchers:
            watchers.remove(watcher)

    def close(self) -> None:
        """Stop recording and tell every watcher it is over (None in its queue)."""
        for name, watchers in self._watchers.items():
            self.buses[name].tap = None
            for watcher in watchers:
                if watcher.queue.full():
                    watcher.queue.get_nowait()  # the end matters more than one more record
                watcher.queue.put_nowait(None)
            watchers.clear()

    def recent(self, bus: str) -> list[Record]:
        return list(self.rings[bus])

    def _tap(
        self,
        bus: str,
        transaction: Transaction,
        attempt: int,
        started: float,
        result: Exchange | LineError,
    ) -> None:
        # On the bus's time: keep it to a record and a few appends, and never raise.
        try:
            record = _record(next(self._seq), bus, transaction, attempt, started, result)
            self.rings[bus].append(record)
            self.recorded += 1
            for watcher in self._watchers[bus]:
                if watcher.queue.full():
                    watcher.dropped += 1
                else:
                    watcher.queue.put_nowait(record)
        except Exception:
            log.exception("traffic monitor: recording failed")

    # -- what the pages and the API show ---------------------------------------------------

    def to_json(self, record: Record) -> dict[str, Any]:
        label = self.drives.get((record.bus, record.address))
        profile = label.profile if label is not None else None
        meaning_reply = record.reply if record.outcome in ("ok", "exception") else None
        return {
            "seq": record.seq,
            "time": iso_time(record.at),
            "bus": record.bus,
            "client": record.client,
            "drive": label.name if label else None,
            "unit_id": label.unit_id if label else None,
            "address": record.address,
            "function": f"{record.pdu[0]:02X}H" if record.pdu else "",
            "meaning": describe(record.pdu, meaning_reply, profile),
            "outcome": _outcome_words(record, profile),
            "attempt": record.attempt,
            "latency_ms": round(record.latency_s * 1000, 1),
            **self.timing(record),
            "request_hex": build_frame(record.address, record.pdu).hex(" "),
            "reply_hex": _reply_hex(record),
        }

    def timing(self, record: Record) -> dict[str, float | None]:
        """The attempt's time split: queue wait, bytes on the wire, the drive's turnaround
        (None without a reply: a timeout, a broadcast)."""
        bus = self.buses.get(record.bus)
        if bus is None:
            return {"queue_ms": _ms(record.queue_s), "wire_ms": None, "turnaround_ms": None}
        char = bus.settings.line.char_format
        wire = char.wire_time_s(len(record.pdu) + 3)  # address, PDU, CRC
        turnaround = None
        if record.reply is not None:
            reply = (
                len(record.reply) + 3
                if record.outcome in ("ok", "exception")
                else len(record.reply)
            )
            wire += char.wire_time_s(reply)
            if record.busy_s is not None:
                turnaround = max(0.0, record.busy_s - wire)
        return {
            "queue_ms": _ms(record.queue_s),
            "wire_ms": _ms(wire),
            "turnaround_ms": None if turnaround is None else _ms(turnaround),
        }


def _ms(seconds: float) -> float:
    return round(seconds * 1000, 2)


def _record(
    seq: int,
    bus: str,
    transaction: Transaction,
    attempt: int,
    started: float,
    result: Exchange | LineError,
) -> Record:
    reply: bytes | None
    busy: float | None = None
    if isinstance(result, Exchange):
        reply = result.reply_pdu
        busy = result.busy_s if reply is not None else None
        if reply is None:
            outcome = "broadcast"
        else:
            outcome = "exception" if reply and reply[0] & 0x80 else "ok"
    elif isinstance(result, ReplyTimeout):
        outcome, reply = "timeout", result.received or None
    elif isinstance(result, BadReply):
        outcome, reply = result.kind, result.frame or None
    elif isinstance(result, PortError):
        outcome, reply = "port_lost", None
    else:
        outcome, reply = "error", None
    return Record(
        seq=seq,
        at=time.time(),
        bus=bus,
        client=transaction.client,
        address=transaction.address,
        pdu=transaction.pdu,
        attempt=attempt,
        latency_s=time.monotonic() - started,
        outcome=outcome,
        reply=reply,
        queue_s=_queued_for(transaction, attempt, started),
        busy_s=busy,
    )


def _queued_for(transaction: Transaction, attempt: int, started: float) -> float:
    """In the queue before the first attempt; a retry (or a transaction built without the
    queue's time) waited none."""
    if attempt or not transaction.queued_at:
        return 0.0
    return max(0.0, started - transaction.queued_at)


def _outcome_words(record: Record, profile: DriveProfile | None) -> str:
    """ "ok", "exception 02H illegal_data_address", "timeout", "crc error", "retry 1: ok"."""
    outcome = record.outcome
    if outcome == "exception" and record.reply is not None and len(record.reply) > 1:
        code = record.reply[1]
        outcome = f"exception {code:02X}H {exceptions_of(profile).name(code)}"
    elif outcome == "crc":
        outcome = "crc error"
    elif outcome == "port_lost":
        outcome = "port lost"
    elif outcome not in ("ok", "broadcast", "timeout", "error"):
        outcome = f"bad reply ({outcome})"
    return f"retry {record.attempt}: {outcome}" if record.attempt else outcome


def _reply_hex(record: Record) -> str:
    if record.reply is None:
        return ""
    if record.outcome in ("ok", "exception"):
        return build_frame(record.address, record.reply).hex(" ")
    return record.reply.hex(" ")  # bytes as they came: a bad reply is shown raw
