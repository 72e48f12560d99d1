"""Drives that may still owe replies to requests that timed out, and how the bus catches up.

RTU has no transaction id. A drive slower than the response timeout (a long P14.03, an EEPROM
write, a serial device server on a slow link) answers a request after the gateway gave up on it,
and that reply looks exactly like the answer to the next request of the same function and length
to the same drive: two SCADA clients got each other's registers, silently. The drain after a
timeout catches a reply that is only a little late, not one later than the drain.

So after a timeout the drive is marked as owing, and before anything else goes to it the bus
sends a diagnostic echo (08H, sub-function 0000) carrying a fresh value. A drive answers in
order: every frame that comes before that echo answers an older request and is set aside
(counted as a late reply); once the echo is back, nothing older is in flight. A device without
08H answers exception 01H, which comes in order just the same. The echo costs one short
transaction after a timeout, and nothing while drives answer in time.
"""

from __future__ import annotations

import logging

from gateway.modbus.functions import DIAGNOSTICS
from gateway.modbus.rtu import build_frame

log = logging.getLogger(__name__)

LOOP_BACK = b"\x00\x00"
"""08H sub-function 0000, return query data: the reply repeats the request."""


class LateReplies:
    """One bus's drives that may owe replies; the echo that catches up with each."""

    def __init__(self, bus: str) -> None:
        self.bus = bus
        self.owing: dict[int, float] = {}
        """Address → when the first request it hasn't answered since went out (monotonic)."""
        self._value = 0
        self._told: set[int] = set()

    def timed_out(self, address: int, sent_at: float) -> None:
        """A request to `address` got no reply in time: its reply may still come."""
        self.owing.setdefault(address, sent_at)

    def echo_frame(self, address: int) -> bytes:
        """An 08H echo request with a value no earlier echo in flight carries."""
        self._value = self._value % 0xFFFF + 1
        return build_frame(address, bytes((DIAGNOSTICS,)) + LOOP_BACK + self._value.to_bytes(2))

    def seen(
        self, address: int, late: tuple[float, ...], timeout_s: float, asked_at: float | None
    ) -> None:
        """Late replies from `address` were set aside (the first to a request sent at
        `asked_at`, or else the first it owes): say once what they suggest."""
        if not late or address in self._told:
            return
        self._told.add(address)
        since = asked_at if asked_at is not None else self.owing.get(address)
        after = f" about {(late[0] - since) * 1000:.0f} ms after its request," if since else ""
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

    def caught_up(self, address: int) -> None:
        """The echo came back: nothing older is in flight from `address`."""
        self.owing.pop(address, None)
