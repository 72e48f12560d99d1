"""Deadlines for the console's HTTP clients: a request's head, then its body, must arrive in time.

aiohttp reads a request with no deadline of its own: a client that connects and sends half a
request line (or its headers, or a body shorter than its Content-Length) and then nothing holds
its connection until aiohttp's keep-alive timeout, an hour by default; two hundred of them are
two hundred sockets nobody counts. Here every connection is wrapped (`Deadlined`, between the
listener and aiohttp's own protocol, which it passes everything on to) and held to
`console.request_timeout_s`:

    head  from connecting, or from the first byte of a later request, until aiohttp has parsed
          the request's head (it calls the handler: `mark_requests` sees it start)
    body  from then until the body is all there (whether the handler has read it yet or not)

A connection that misses either is aborted and counted in `HttpTimeouts`. Between requests a
connection may sit idle for `KEEP_ALIVE_S` (aiohttp's keep-alive), as browsers keep them.

A request line longer than `bad_requests.MAX_REQUEST_LINE` is answered 414 here and the
connection closed: aiohttp's parser would answer 400 and log a traceback for each.
"""

from __future__ import annotations

import asyncio
import logging
import ssl
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from enum import Enum
from typing import Final, cast

from aiohttp import StreamReader, web

from gateway.console.bad_requests import MAX_REQUEST_LINE, BadRequests
from gateway.logs import repeated

log = logging.getLogger(__name__)

KEEP_ALIVE_S: Final = 60.0
"""An idle connection between two requests is closed after this (aiohttp's default: 3630 s)."""


@dataclass(slots=True)
class HttpTimeouts:
    """Connections closed for a request that did not arrive in time, by what was missing."""

    head: int = 0
    body: int = 0


class _Phase(Enum):
    HEAD = "head"
    """Waiting for a request's head: from connecting, or from a later request's first byte."""
    BODY = "body"
    """The head is there, the body isn't yet."""
    HANDLING = "handling"
    IDLE = "idle"
    """Between requests: aiohttp's keep-alive decides."""


class RequestDeadlines:
    """The deadlines of every connection of one listener, and what they closed."""

    def __init__(self, timeout_s: float, bad: BadRequests | None = None) -> None:
        self.timeout_s = timeout_s
        self.closed = HttpTimeouts()
        self.bad = bad if bad is not None else BadRequests()

    def wrap(self, handler: asyncio.Protocol) -> Deadlined:
        return Deadlined(self, handler)


class Deadlined(asyncio.Protocol):
    """One connection: aiohttp's protocol (`handler`) inside, its deadlines around it."""

    def __init__(self, deadlines: RequestDeadlines, handler: asyncio.Protocol) -> None:
        self.deadlines = deadlines
        self.handler = handler
        self._transport: asyncio.Transport | None = None
        self._phase = _Phase.HEAD
        self._timer: asyncio.TimerHandle | None = None
        self._body_done: StreamReader | None = None
        self._line_bytes: int | None = 0
        """Bytes of the request line so far; None once it is whole (or refused)."""

    # -- the transport's side: passed on to aiohttp ------------------------------------------

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self._transport = cast(asyncio.Transport, transport)
        self.handler.connection_made(transport)
        self._arm()

    def data_received(self, data: bytes) -> None:
        if self._phase is _Phase.IDLE:
            self._phase = _Phase.HEAD  # a later request has begun: its head is due
            self._line_bytes = 0
            self._arm()
        if self._line_bytes is not None and not self._line_fits(data):
            return
        self.handler.data_received(data)

    def eof_received(self) -> bool | None:
        return self.handler.eof_received()

    def connection_lost(self, exc: Exception | None) -> None:
        self._cancel()
        self.handler.connection_lost(exc)

    def pause_writing(self) -> None:
        self.handler.pause_writing()

    def resume_writing(self) -> None:
        self.handler.resume_writing()

    # -- aiohttp's side: a request has started, has ended ------------------------------------

    def request_started(self, request: web.BaseRequest) -> None:
        self._cancel()
        if request.body_exists and not request.content.is_eof():
            self._phase = _Phase.BODY
            self._body_done = request.content
            self._arm()
        else:
            self._phase = _Phase.HANDLING

    def _line_fits(self, data: bytes) -> bool:
        """Counts a request line's bytes; False (answered 414, closing) when it is too long."""
        assert self._line_bytes is not None
        end = data.find(b"\n")
        self._line_bytes += len(data) if end < 0 else end
        if self._line_bytes <= MAX_REQUEST_LINE + 1:  # + 1: the "\r" before the "\n"
            if end >= 0:
                self._line_bytes = None
            return True
        self._line_bytes = None
        transport = self._transport
        if transport is not None and not transport.is_closing():
            self._cancel()
            self.deadlines.bad.refused(414, _peer(transport), "request line too long")
            transport.write(URI_TOO_LONG)
            transport.close()
        return False

    def request_ended(self) -> None:
        self._cancel()
        self._phase = _Phase.IDLE
        self._body_done = None

    # -- inside --------------------------------------------------------------------------------

    def _arm(self) -> None:
        self._cancel()
        loop = asyncio.get_running_loop()
        self._timer = loop.call_later(self.deadlines.timeout_s, self._expired)

    def _cancel(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    def _expired(self) -> None:
        self._timer = None
        transport = self._transport
        if transport is None or transport.is_closing():
            return
        phase = self._phase
        if phase is _Phase.BODY and self._body_done is not None and self._body_done.is_eof():
            self._phase = _Phase.HANDLING  # all there in time: the handler takes its time
            return
        if phase is _Phase.HEAD:
            self.deadlines.closed.head += 1
        elif phase is _Phase.BODY:
            self.deadlines.closed.body += 1
        else:
            return
        log.info(
            "console: %s closed: no complete request %s within %g s (console.request_timeout_s)",
            _peer(transport),
            phase.value,
            self.deadlines.timeout_s,
            extra=repeated("console-slow"),
        )
        transport.abort()  # not close: nothing it has sent is worth an answer


def _peer(transport: asyncio.BaseTransport) -> str:
    peer = transport.get_extra_info("peername") or ("?", 0)
    return str(peer[0])


_URI_TOO_LONG_BODY: Final = (
    b'{"ok": false, "error": "the request line is over %d bytes"}' % MAX_REQUEST_LINE
)
URI_TOO_LONG: Final = (
    b"HTTP/1.1 414 URI Too Long\r\nContent-Type: application/json\r\n"
    b"Content-Length: %d\r\nConnection: close\r\n\r\n"
    % len(_URI_TOO_LONG_BODY)
    + _URI_TOO_LONG_BODY
)


@web.middleware
async def mark_requests(
    request: web.Request, handler: Callable[[web.Request], Awaitable[web.StreamResponse]]
) -> web.StreamResponse:
    """Tells the connection's deadlines that a request's head has come, and when it has ended."""
    transport = request.transport
    deadlined = transport.get_protocol() if transport is not None else None
    if not isinstance(deadlined, Deadlined):
        return await handler(request)  # a test client without a listener of ours
    deadlined.request_started(request)
    try:
        return await handler(request)
    finally:
        deadlined.request_ended()


class DeadlinedSite(web.BaseSite):
    """aiohttp's TCPSite, with each connection wrapped in its deadlines."""

    def __init__(
        self,
        runner: web.BaseRunner,
        host: str,
        port: int,
        deadlines: RequestDeadlines,
        ssl_context: ssl.SSLContext | None = None,
    ) -> None:
        super().__init__(runner, ssl_context=ssl_context)
        self.host = host
        self.port = port
        self.deadlines = deadlines

    @property
    def name(self) -> str:
        scheme = "https" if self._ssl_context else "http"
        return f"{scheme}://{self.host}:{self.port}"

    async def start(self) -> None:
        await super().start()
        server = self._runner.server
        assert server is not None, "runner.setup() first"
        loop = asyncio.get_running_loop()
        self._server = await loop.create_server(
            lambda: self.deadlines.wrap(server()),
            self.host,
            self.port,
            ssl=self._ssl_context,
            # HTTPS: the handshake comes before any of it, and asyncio gives it 60 s by default.
            ssl_handshake_timeout=self.deadlines.timeout_s if self._ssl_context else None,
            backlog=self._backlog,
            reuse_address=True,
        )
