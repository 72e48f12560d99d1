"""The Modbus/TCP Security listener's TLS handshakes: timed, and counted when they fail.

asyncio (and uvloop) run the handshake before the server sees a connection at all: a client
that sends half a ClientHello and stops holds a socket for asyncio's default 60 s, and one with
an untrusted certificate vanishes, and neither is on any record. The listener is given
`first_request_timeout_s` as its handshake timeout (the loop closes a stalled handshake then);
this module counts what came of each handshake by watching the one object both loops drive it
through: the context's `sslobject_class` (documented for exactly this: a subclass of
`ssl.SSLObject` the context creates for each connection). Its `do_handshake` is called when the
handshake starts and each time more of it arrives: an `SSLError` other than "want more" is a
failed handshake; one neither done nor failed when the timeout has passed was closed by the loop
(a stalled client, or one that left halfway: the loop tells nobody which).
"""

from __future__ import annotations

import asyncio
import logging
import ssl
from typing import TYPE_CHECKING

from gateway.logs import repeated

if TYPE_CHECKING:
    from gateway.tcp.stats import TcpStats

log = logging.getLogger(__name__)

COUNT_MARGIN_S = 0.1
"""Our look comes this long after the loop's own timeout, which closes the connection."""


class HandshakeWatch:
    def __init__(self, stats: TcpStats, timeout_s: float) -> None:
        self.stats = stats
        self.timeout_s = timeout_s
        """Given to the listener as its `ssl_handshake_timeout`."""
        self._pending: dict[ssl.SSLObject, asyncio.TimerHandle] = {}

    @property
    def pending(self) -> int:
        """Handshakes under way now."""
        return len(self._pending)

    def watch(self, context: ssl.SSLContext) -> None:
        """Every handshake of connections made with `context` from now on is watched."""
        watch = self

        class WatchedObject(ssl.SSLObject):
            def do_handshake(self) -> None:
                if self not in watch._pending:
                    watch._started(self)
                try:
                    super().do_handshake()
                except (ssl.SSLWantReadError, ssl.SSLWantWriteError):
                    raise  # the rest of the handshake is still to come
                except ssl.SSLError as exc:
                    watch._failed(self, exc)
                    raise
                watch._done(self)

        context.sslobject_class = WatchedObject

    def _started(self, handshake: ssl.SSLObject) -> None:
        loop = asyncio.get_running_loop()
        due = self.timeout_s + COUNT_MARGIN_S
        self._pending[handshake] = loop.call_later(due, self._timed_out, handshake)

    def _done(self, handshake: ssl.SSLObject) -> None:
        timer = self._pending.pop(handshake, None)
        if timer is not None:
            timer.cancel()

    def _failed(self, handshake: ssl.SSLObject, exc: ssl.SSLError) -> None:
        self._done(handshake)
        self.stats.tls_handshakes_failed += 1
        log.info("TLS handshake failed: %s", exc.reason or exc, extra=repeated("tls-failed"))

    def _timed_out(self, handshake: ssl.SSLObject) -> None:
        if self._pending.pop(handshake, None) is None:
            return
        self.stats.tls_handshake_timeouts += 1
        log.info(
            "a TLS client closed: handshake not done within %g s (first_request_timeout_s)",
            self.timeout_s,
            extra=repeated("tls-slow"),
        )

    def stop(self) -> None:
        for timer in self._pending.values():
            timer.cancel()
        self._pending.clear()
