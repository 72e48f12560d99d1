"""The line's counters as a diagnostics page shows them: per bus and per drive, since the
gateway started and over the last minute.

The bus counts anyway (`BusStats`, `DriveStats`); the console's sampler copies the figures
once a second into a short window (`CounterWindow`), so the last minute is a difference of two
copies and nothing is added to the bus's work. The Modbus-TCP clients and the MQTT session are
read when asked, through their owners' small accessors (`ModbusTcpServer.clients`,
`MqttBridge.status`).
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Final, Protocol

from gateway.bus import BusStats
from gateway.bus.bus import DriveStats
from gateway.poller.drive_state import iso_time
from gateway.profile import STANDARD_EXCEPTIONS, ExceptionNames
from gateway.tcp.server import ClientStatus

if TYPE_CHECKING:  # the console never loads aiomqtt for a gateway without MQTT
    from gateway.mqtt.stats import SessionStatus

MINUTE_S: Final = 60.0
CRC: Final = "crc"
"""The bad reply kind of a frame whose CRC did not match (`gateway.errors.BadReply.kind`)."""


@dataclass(frozen=True, slots=True)
class LineCounts:
    """What the line did for a bus or a drive, as plain numbers: a copy, safe to keep."""

    sent: int
    """Frames sent: every attempt, retries included."""
    timeouts: int
    crc_errors: int
    bad_replies: int
    """Replies that were not valid in another way (truncated, wrong address or function...)."""
    exceptions: tuple[tuple[int, int], ...]
    """(exception code, count), by code."""
    retries: int
    late_replies: int
    failed: int
    """Requests that got no usable reply after every retry."""
    resyncs: int = 0
    """Markers sent to bring a drive back in step (`gateway.bus.late_replies`)."""

    @classmethod
    def of(cls, stats: BusStats | DriveStats) -> LineCounts:
        bad = stats.bad_replies
        crc = bad.get(CRC, 0)
        return cls(
            stats.transactions,
            stats.timeouts,
            crc,
            sum(bad.values()) - crc,
            tuple(sorted(stats.exceptions.items())),
            stats.retries,
            stats.late_replies,
            stats.failed,
            stats.resyncs,
        )

    @property
    def replies(self) -> int:
        """Frames sent that got a valid reply (an exception is one)."""
        return max(0, self.sent - self.timeouts - self.crc_errors - self.bad_replies)

    def minus(self, earlier: LineCounts) -> LineCounts:
        before = dict(earlier.exceptions)
        exceptions = tuple(
            (code, count - before.get(code, 0))
            for code, count in self.exceptions
            if count != before.get(code, 0)
        )
        return LineCounts(
            self.sent - earlier.sent,
            self.timeouts - earlier.timeouts,
            self.crc_errors - earlier.crc_errors,
            self.bad_replies - earlier.bad_replies,
            exceptions,
            self.retries - earlier.retries,
            self.late_replies - earlier.late_replies,
            self.failed - earlier.failed,
            self.resyncs - earlier.resyncs,
        )

    def to_json(self, exceptions: ExceptionNames) -> dict[str, Any]:
        """`exceptions`: the words of the drive's profile (of the line's drives, for a line)."""
        return {
            "sent": self.sent,
            "replies": self.replies,
            "timeouts": self.timeouts,
            "crc_errors": self.crc_errors,
            "bad_replies": self.bad_replies,
            "exceptions": [
                {"code": f"{code:02X}H", "name": exceptions.name(code), "count": count}
                for code, count in self.exceptions
            ],
            "retries": self.retries,
            "late_replies": self.late_replies,
            "failed": self.failed,
            "resyncs": self.resyncs,
        }


NOTHING: Final = LineCounts(0, 0, 0, 0, (), 0, 0, 0)


class CounterWindow:
    """A bus's or a drive's counts, once a second for a minute and a bit."""

    def __init__(self) -> None:
        self._copies: deque[tuple[float, LineCounts]] = deque(maxlen=int(MINUTE_S) + 2)

    def add(self, at: float, counts: LineCounts) -> None:
        self._copies.append((at, counts))

    def last_minute(self) -> LineCounts:
        if len(self._copies) < 2:
            return NOTHING
        last_at, last = self._copies[-1]
        first = next(c for at, c in self._copies if last_at - at <= MINUTE_S + 0.5)
        return last.minus(first)


class BusCounters:
    """The windows of one bus and its drives (by address), and since when it counts."""

    def __init__(self, stats: BusStats) -> None:
        self.stats = stats
        """The bus's own object: a bus replaced by a reload is a new one, counting from zero."""
        self.since = time.time()
        self.bus = CounterWindow()
        self.drives: dict[int, CounterWindow] = {}

    def sample(self, at: float, drive_stats: Mapping[int, DriveStats]) -> None:
        self.bus.add(at, LineCounts.of(self.stats))
        for address, stats in list(drive_stats.items()):
            window = self.drives.get(address)
            if window is None:
                window = self.drives[address] = CounterWindow()
            window.add(at, LineCounts.of(stats))

    def view(
        self,
        drive_stats: Mapping[int, DriveStats],
        names: Mapping[int, str],
        exceptions: Mapping[int, ExceptionNames],
    ) -> dict[str, Any]:
        """`names`, `exceptions`: each configured drive's name and its profile's words for
        exceptions, by address (an address no drive has gets the Modbus standard's)."""
        drives = []
        for address in sorted(set(drive_stats) | set(names)):
            counted = drive_stats.get(address)
            window = self.drives.get(address)
            words = exceptions.get(address, STANDARD_EXCEPTIONS)
            since_start = NOTHING if counted is None else LineCounts.of(counted)
            last_minute = NOTHING if window is None else window.last_minute()
            drives.append(
                {
                    "address": address,
                    "drive": names.get(address),
                    "since_start": since_start.to_json(words),
                    "last_minute": last_minute.to_json(words),
                }
            )
        words = line_words(exceptions.values())
        stats = self.stats
        return {
            "counting_since": iso_time(self.since),
            "requests": stats.requests,
            "queue_full": stats.queue_full,
            "coalesced": stats.coalesced,
            "port_errors": stats.port_errors,
            "reopens": stats.reopens,
            "since_start": LineCounts.of(stats).to_json(words),
            "last_minute": self.bus.last_minute().to_json(words),
            "drives": drives,
        }


def line_words(tables: Iterable[ExceptionNames]) -> ExceptionNames:
    """A line's exceptions in its drives' words when they all speak alike (a line of INVT
    drives), else in the Modbus standard's."""
    distinct = set(tables)
    return distinct.pop() if len(distinct) == 1 else STANDARD_EXCEPTIONS


class TcpClients(Protocol):
    """The Modbus-TCP server as far as diagnostics read it (`ModbusTcpServer`)."""

    def clients(self) -> list[ClientStatus]: ...


class MqttSession(Protocol):
    """The MQTT bridge as far as diagnostics read it (`MqttBridge`)."""

    def status(self) -> SessionStatus: ...


class OpcUaSessions(Protocol):
    """The OPC UA server as far as diagnostics read it (`OpcUaServer`): each logged-in
    session's `{"user", "role", "since"}`."""

    def sessions(self) -> list[dict[str, str]]: ...


def tcp_clients_json(server: TcpClients) -> list[dict[str, Any]]:
    return [
        {
            "client": client.client,
            "address": client.client.removeprefix("tcp:"),
            "connected_since": iso_time(client.connected_at),
            "requests": client.requests,
            "errors": client.errors,
            "in_flight": client.in_flight,
            "tls": client.tls,
            "role": client.role,
        }
        for client in server.clients()
    ]
