"""Clients that connect to the console and send half a request: closed within
`console.request_timeout_s`, counted in /metrics, and nobody else waits for them.

Real sockets against the gateway with its console on the simulated line; the good client is
aiohttp's, the slow ones raw TCP connections that stop halfway.
"""

from __future__ import annotations

import asyncio
import contextlib
import time

from gateway.config import MetricsConfig
from gateway.console.deadlines import HttpTimeouts
from gateway.instruments.simulator import SimulatedLine
from tests.support import RecordProperty, free_port, present, running_gateway
from tests.support.console_support import VIEWER_PASSWORD, console_client, console_config
from tests.support.http import http_get

HALF_A_HEAD = b"GET /api/overview HTTP/1.1\r\nHost: 127.0.0.1\r\nAccept: applica"
HALF_A_BODY = (
    b"POST /api/login HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
    b'Content-Length: 60\r\n\r\n{"name": "victor", "pass'
)


async def closed_after(reader: asyncio.StreamReader, started: float) -> float:
    """Seconds from `started` until the gateway closed the connection (10 s at most)."""
    with contextlib.suppress(ConnectionError):  # aborted: a reset is a close too
        await asyncio.wait_for(reader.read(), 10)
    return time.monotonic() - started


async def half_requests(port: int, count: int, sent: bytes) -> list[asyncio.Task[float]]:
    """`count` connections that send `sent` and then nothing; each one's task ends when the
    gateway closes it, with the seconds that took."""
    waits = []
    for _ in range(count):
        reader, writer = await asyncio.open_connection("127.0.0.1", port)
        writer.write(sent)
        waits.append(asyncio.create_task(closed_after(reader, time.monotonic())))
        waits[-1].add_done_callback(lambda _, writer=writer: writer.close())  # type: ignore[misc]
    return waits


async def test_half_requests_are_closed_in_time_and_counted_while_others_are_served(
    line: SimulatedLine, record_property: RecordProperty
) -> None:
    metrics_port = free_port()
    metrics = MetricsConfig(enabled=True, host="127.0.0.1", port=metrics_port)
    config = console_config(line.path, request_timeout_s=1).model_copy(update={"metrics": metrics})
    async with running_gateway(config) as app, console_client(app) as web:
        port = present(app.console).port
        heads = await half_requests(port, 200, HALF_A_HEAD)
        bodies = await half_requests(port, 10, HALF_A_BODY)
        silent = await half_requests(port, 10, b"")
        # Meanwhile an operator logs in and reads, as often as it likes.
        served = 0
        started = time.monotonic()
        while time.monotonic() - started < 1.2:
            if served == 0:
                assert (await web.login("victor", VIEWER_PASSWORD)).status == 200
            assert len((await web.get_json("/api/overview"))["drives"]) == 2
            served += 1
        waited = await asyncio.gather(*heads, *bodies, *silent)
        assert max(waited) < 2.5, max(waited)
        assert min(waited) > 0.8, min(waited)
        closed = present(app.console).deadlines.closed
        assert (closed.head, closed.body) == (210, 10)
        # The one that was served kept its connection (keep-alive) and is served still.
        assert len((await web.get_json("/api/overview"))["drives"]) == 2
        _, _, text = await http_get(metrics_port, "/metrics")
        assert 'invt_gateway_console_request_timeouts_total{phase="head"} 210.0' in text
        assert 'invt_gateway_console_request_timeouts_total{phase="body"} 10.0' in text
        record_property(
            "figure:console half requests",
            f"200 half heads, 10 half bodies, 10 silent: closed {min(waited):.2f}-"
            f"{max(waited):.2f} s after connecting (request_timeout_s 1), counted; "
            f"another client served {served} times meanwhile",
        )


async def test_a_long_answer_is_not_a_slow_client(line: SimulatedLine) -> None:
    # The deadline is the client's: a request that came whole in time is not cut off while the
    # gateway answers at length (the live stream, which a page keeps open for hours).
    async with running_gateway(console_config(line.path, request_timeout_s=1)) as app:
        async with console_client(app) as web:
            assert (await web.login("victor", VIEWER_PASSWORD)).status == 200
            events = 0
            async with web.session.get(f"{web.base}/api/live") as stream:
                started = time.monotonic()
                async for text in stream.content:
                    events += text.startswith(b"event: overview")
                    if time.monotonic() - started > 2.5:
                        break
            assert events >= 4  # one every 0.5 s, on and on past the 1 s deadline
        assert present(app.console).deadlines.closed == HttpTimeouts(head=0, body=0)
