"""A very small HTTP/1.1 server on asyncio streams for /metrics and /health.

It runs on the gateway's own event loop on purpose: if that loop is stuck, /health goes
unanswered, which is exactly what a health check must notice (a server thread would keep
answering "fine" for a gateway that no longer moves). GET and HEAD only, one request per
connection, bounded header size and time: it serves Prometheus and health probes, nothing else.
"""

from __future__ import annotations

import asyncio
import contextlib
import inspect
import logging
from collections.abc import Awaitable, Callable, Mapping
from dataclasses import dataclass
from http import HTTPStatus

from gateway.listen import cannot_listen

log = logging.getLogger(__name__)

REQUEST_TIMEOUT_S = 5.0
MAX_HEADER_LINES = 64
MAX_LINE = 8192


@dataclass(frozen=True, slots=True)
class Response:
    status: int
    content_type: str
    body: bytes


# A route answers at once, or (a coroutine) gives the loop back while it makes its answer.
Route = Callable[[], Response | Awaitable[Response]]


def text_response(status: int, text: str) -> Response:
    return Response(status, "text/plain; charset=utf-8", text.encode())


class HttpEndpoint:
    def __init__(self, host: str, port: int, routes: Mapping[str, Route]) -> None:
        self.host = host
        self.requested_port = port
        self.routes = routes
        self._server: asyncio.Server | None = None

    @property
    def port(self) -> int:
        """The bound port (useful when configured as 0)."""
        assert self._server is not None, "start() first"
        return int(self._server.sockets[0].getsockname()[1])

    async def start(self) -> None:
        host, port = self.host, self.requested_port
        try:
            self._server = await asyncio.start_server(
                self._serve, host, port, reuse_address=True, limit=MAX_LINE
            )
        except OSError as exc:
            raise cannot_listen("metrics and health", host, port, "metrics.host/port", exc) from exc

    async def stop(self) -> None:
        if self._server is not None:
            self._server.close()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._server.wait_closed(), 1.0)

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            request = await asyncio.wait_for(_read_request(reader), REQUEST_TIMEOUT_S)
            answer, head_only = self._respond(request)
            response = await answer if inspect.isawaitable(answer) else answer
            writer.write(_encode(response, head_only))
            await writer.drain()
        except (TimeoutError, ConnectionError, asyncio.IncompleteReadError, ValueError):
            pass  # a probe that hung up or sent garbage gets nothing more
        except Exception:
            log.exception("HTTP endpoint: error answering a request")
        finally:
            writer.close()
            with contextlib.suppress(Exception):
                await asyncio.wait_for(writer.wait_closed(), 1.0)

    def _respond(self, request: tuple[str, str]) -> tuple[Response | Awaitable[Response], bool]:
        method, target = request
        if method not in ("GET", "HEAD"):
            return text_response(HTTPStatus.METHOD_NOT_ALLOWED, "GET or HEAD only\n"), False
        route = self.routes.get(target.split("?", 1)[0])
        if route is None:
            known = " ".join(sorted(self.routes))
            return text_response(HTTPStatus.NOT_FOUND, f"not found; try {known}\n"), False
        return route(), method == "HEAD"


async def _read_request(reader: asyncio.StreamReader) -> tuple[str, str]:
    """(method, target) of one request; its headers are read and ignored."""
    request_line = (await reader.readuntil(b"\n")).decode("latin-1").strip()
    parts = request_line.split()
    if len(parts) != 3 or not parts[2].startswith("HTTP/"):
        raise ValueError(f"not an HTTP request line: {request_line[:80]!r}")
    for _ in range(MAX_HEADER_LINES):
        if (await reader.readuntil(b"\n")).strip() == b"":
            return parts[0], parts[1]
    raise ValueError("too many header lines")


def _encode(response: Response, head_only: bool) -> bytes:
    reason = HTTPStatus(response.status).phrase
    head = (
        f"HTTP/1.1 {response.status} {reason}\r\n"
        f"Content-Type: {response.content_type}\r\n"
        f"Content-Length: {len(response.body)}\r\n"
        "Cache-Control: no-store\r\n"
        "Connection: close\r\n\r\n"
    ).encode("latin-1")
    return head if head_only else head + response.body
