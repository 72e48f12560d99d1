"""The console's request deadlines on a real loopback socket, with aiohttp behind them: half a
head or half a body is closed after `request_timeout_s` and counted by what was missing; a slow
answer, or a connection kept alive between requests, is not a slow client."""

from __future__ import annotations

import asyncio
import time
from collections.abc import AsyncIterator

import pytest
from aiohttp import web

from gateway.console.deadlines import DeadlinedSite, RequestDeadlines, mark_requests
from tests.support import free_port

TIMEOUT_S = 0.3
SLOW_ANSWER_S = 2 * TIMEOUT_S


async def echo(request: web.Request) -> web.Response:
    return web.Response(body=await request.read())


async def slow(request: web.Request) -> web.Response:
    await asyncio.sleep(SLOW_ANSWER_S)  # an answer that takes its time, as a drive read may
    return web.Response(text="done")


@pytest.fixture
async def site() -> AsyncIterator[tuple[int, RequestDeadlines]]:
    app = web.Application(middlewares=[mark_requests])
    app.router.add_post("/echo", echo)
    app.router.add_get("/slow", slow)
    runner = web.AppRunner(app)
    await runner.setup()
    deadlines = RequestDeadlines(TIMEOUT_S)
    port = free_port()
    await DeadlinedSite(runner, "127.0.0.1", port, deadlines).start()
    try:
        yield port, deadlines
    finally:
        await runner.cleanup()


async def closed_after(reader: asyncio.StreamReader, started: float) -> float:
    """Seconds from `started` until the server closed the connection (nothing was answered)."""
    assert await asyncio.wait_for(reader.read(), 5) == b""
    return time.monotonic() - started


async def test_half_a_head_is_closed_in_time_and_counted(
    site: tuple[int, RequestDeadlines],
) -> None:
    port, deadlines = site
    started = time.monotonic()
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    writer.write(b"GET /slow HTTP/1.1\r\nHost: x\r\n")  # the head's blank line never comes
    waited = await closed_after(reader, started)
    writer.close()
    assert TIMEOUT_S * 0.9 < waited < TIMEOUT_S + 1.0
    assert (deadlines.closed.head, deadlines.closed.body) == (1, 0)


async def test_half_a_body_is_closed_in_time_and_counted(
    site: tuple[int, RequestDeadlines],
) -> None:
    port, deadlines = site
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    writer.write(b"POST /echo HTTP/1.1\r\nHost: x\r\nContent-Length: 10\r\n\r\nabc")
    started = time.monotonic()
    waited = await closed_after(reader, started)
    writer.close()
    assert waited < TIMEOUT_S + 1.0
    assert (deadlines.closed.head, deadlines.closed.body) == (0, 1)


async def test_a_slow_answer_and_a_pause_between_requests_are_not_slow_clients(
    site: tuple[int, RequestDeadlines],
) -> None:
    port, deadlines = site
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    try:
        writer.write(b"GET /slow HTTP/1.1\r\nHost: x\r\n\r\n")
        head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), 5)
        assert head.startswith(b"HTTP/1.1 200")
        assert await asyncio.wait_for(reader.readexactly(4), 5) == b"done"
        await asyncio.sleep(2 * TIMEOUT_S)  # the thing under test: idle between two requests
        writer.write(b"POST /echo HTTP/1.1\r\nHost: x\r\nContent-Length: 5\r\n\r\nhello")
        head = await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), 5)
        assert head.startswith(b"HTTP/1.1 200")
        assert await asyncio.wait_for(reader.readexactly(5), 5) == b"hello"
    finally:
        writer.close()
    assert (deadlines.closed.head, deadlines.closed.body) == (0, 0)
