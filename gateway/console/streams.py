"""The console's live parts, as server-sent events (`text/event-stream`), which browsers
reconnect by themselves:

    GET /api/live                 `overview` every half second; `?drive=NAME`: its `drive` too
    GET /api/buses/{bus}/traffic  every transaction on the bus from now on (the line monitor)
"""

from __future__ import annotations

import asyncio
import contextlib
import json
from typing import Any, Final

from aiohttp import web

from gateway.console.context import CONSOLE, Console, drive_json
from gateway.console.guard import SECURITY_HEADERS
from gateway.console.replies import http_error, query_limit

LIVE_PERIOD_S: Final = 0.5
"""The overview and a drive's page are pushed this often: live within a second."""
HEARTBEAT_S: Final = 15.0
RECENT_BATCH: Final = 100
"""Transactions kept that a new monitor gets between two turns of the event loop."""


async def live_stream(request: web.Request) -> web.StreamResponse:
    """`overview` events every half second; with `?drive=NAME`, that drive's `drive` too."""
    console = request.app[CONSOLE]
    drive = request.query.get("drive")
    if drive is not None and drive not in console.live.drives:
        raise http_error(404, f"no drive named {drive!r}")
    response = await _open_stream(request)
    try:
        while not console.closing.is_set():
            await _send_event(response, "overview", console.live.overview())
            if drive is not None:
                await _send_event(response, "drive", drive_json(console, drive))
            await _wait(console, LIVE_PERIOD_S)
    except ConnectionError:
        pass  # the page was closed: nothing more to say, nothing to log
    return response


async def traffic_stream(request: web.Request) -> web.StreamResponse:
    """Every transaction on the bus from now on (`?recent=N`: the last N first, kept at all
    times), as `traffic` events."""
    console = request.app[CONSOLE]
    bus = request.match_info["bus"]
    if bus not in console.live.buses:
        raise http_error(404, f"no bus named {bus!r}")
    traffic = console.traffic
    watcher = traffic.watch(bus)
    try:
        response = await _open_stream(request)
        recent = query_limit(request, "recent", default=0)
        if recent:
            for index, kept in enumerate(traffic.recent(bus)[-recent:]):
                await _send_event(response, "traffic", traffic.to_json(kept))
                if index % RECENT_BATCH == RECENT_BATCH - 1:
                    await asyncio.sleep(0)  # 2000 decoded at once would hold the bus's loop
        await _send_event(response, "watching", {"bus": bus})
        while not console.closing.is_set():
            try:
                record = await asyncio.wait_for(watcher.queue.get(), HEARTBEAT_S)
            except TimeoutError:
                await response.write(b": still here\n\n")
                continue
            if record is None:
                break  # the console is stopping
            await _send_event(response, "traffic", traffic.to_json(record))
        return response
    except ConnectionError:
        return response  # the monitor was closed: nothing to log
    finally:
        traffic.leave(watcher)


async def _open_stream(request: web.Request) -> web.StreamResponse:
    response = web.StreamResponse(
        headers={"Content-Type": "text/event-stream", "Cache-Control": "no-store"}
    )
    for name, value in SECURITY_HEADERS.items():
        response.headers[name] = value
    await response.prepare(request)
    return response


async def _send_event(response: web.StreamResponse, event: str, data: Any) -> None:
    await response.write(f"event: {event}\ndata: {json.dumps(data)}\n\n".encode())


async def _wait(console: Console, seconds: float) -> None:
    with contextlib.suppress(TimeoutError):
        await asyncio.wait_for(console.closing.wait(), seconds)
