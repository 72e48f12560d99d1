"""Requests the console refuses for what they are, from anyone: one clear answer each, counted
by status, and logged once a minute in aggregate (`gateway.logs.repeated`), never a traceback.

Anyone who reaches the console's port can send these before logging in, as fast as he likes:

    414  a request line over `MAX_REQUEST_LINE` bytes (`deadlines.Deadlined` answers it before
         aiohttp's parser sees it: the parser would answer 400 and log a traceback each time)
    413  a body over what the endpoint takes (`replies.json_body`)
    400  a request aiohttp's parser refuses (a header too long, a bad method, a bad chunk), a
         body that is not JSON or nested too deeply, a query value out of range

A connection closed under a request (a slow body the deadline cut, a client gone) is no error
of the console's: aiohttp reports it as the handler's exception, which `ConsoleServerLog` keeps
out of the log (the deadline has said why, once a minute). Anything else a handler raises is a
bug of ours and is logged as aiohttp logs it, traceback and all.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Awaitable, Callable
from typing import Any, Final

from aiohttp import web
from aiohttp.http_exceptions import HttpProcessingError

from gateway.logs import repeated

log = logging.getLogger("gateway.console")

MAX_REQUEST_LINE: Final = 8190
"""Bytes of a request line ("GET /path?query HTTP/1.1"): aiohttp's own limit for the URL."""
REFUSED_STATUSES: Final = (400, 413, 414)
"""What a request's own content earns; counted in `console_bad_requests_total{status}`."""

Handler = Callable[[web.Request], Awaitable[web.StreamResponse]]


class BadRequests:
    """Requests refused for their content, by HTTP status; the log's one owner for them."""

    def __init__(self) -> None:
        self.by_status: Counter[int] = Counter()

    def refused(self, status: int, peer: str, reason: str) -> None:
        self.by_status[status] += 1
        log.info(
            "console: %s refused (%d): %s",
            peer,
            status,
            reason,
            extra=repeated(f"console-{status}"),
        )

    @web.middleware
    async def middleware(self, request: web.Request, handler: Handler) -> web.StreamResponse:
        """Counts and logs what a handler refused as 400, 413 or 414."""
        try:
            return await handler(request)
        except web.HTTPException as exc:
            if exc.status in REFUSED_STATUSES:
                self.refused(exc.status, request.remote or "?", exc.text or exc.reason)
            raise

    def server_log(self) -> ConsoleServerLog:
        return ConsoleServerLog(self)


class ConsoleServerLog(logging.LoggerAdapter[logging.Logger]):
    """aiohttp's server logger (its `logger=`): what its parser refused goes to `BadRequests`,
    a connection lost under a request nowhere; every other record as aiohttp sends it."""

    def __init__(self, bad: BadRequests) -> None:
        super().__init__(logging.getLogger("aiohttp.server"))
        self.bad = bad

    def exception(self, msg: object, *args: object, **kwargs: Any) -> None:
        exc = kwargs.get("exc_info")
        if isinstance(exc, HttpProcessingError):
            peer = str(args[0]) if args else "?"
            self.bad.refused(exc.code or 400, peer, exc.message or type(exc).__name__)
            return
        if isinstance(exc, ConnectionError):
            return  # the client went, or a deadline closed it: said where that happened
        super().exception(msg, *args, **kwargs)
