"""Any polled value of a drive over a chosen window: the history page and its JSON API.

    GET /history                       the page: a drive, its values, a window; zoom; CSV
    GET /api/drives/{name}/history     ?keys=a,b&window=15m (or since=&until=, ISO with zone)
                                       &points=600; &format=csv for a file of what is shown

A window within the last 15 minutes comes from the console's live ring (a point a second,
`LiveState`); a longer one from the store's history (a point a `storage.history_step_s`,
`gateway.store.history`), reduced in the database to at most `points` (1 to `MAX_POINTS`: a
chart is not wider) when it holds more, before anything of it is read into memory. Both hold
the same values (`gateway.store.history.values`). Reading the store never waits on a bus,
and at most `MAX_STORE_QUERIES` read it at once: `MAX_WAITING_QUERIES` more wait their turn,
any beyond are answered 503 (a dashboard of many charts over months can't take the box's
memory or CPU).
"""

from __future__ import annotations

import asyncio
import contextlib
import csv
import io
import re
import time
from collections.abc import AsyncIterator, Callable, Sequence
from typing import Any, Final, Protocol, TypeVar

from aiohttp import web

from gateway.console.context import CONSOLE, drive_name, html_page
from gateway.console.live import HISTORY_S
from gateway.console.replies import http_error, time_query
from gateway.console.spreadsheet import text_cell
from gateway.errors import StoreError
from gateway.poller.drive_state import iso_time
from gateway.store.history import Series, Value, series, values

WINDOWS: Final = {"15m": 900.0, "1h": 3600.0, "6h": 6 * 3600.0, "24h": 86400.0, "7d": 7 * 86400.0}
DEFAULT_WINDOW: Final = "15m"
"""The page opens on it (the `selected` option below): the live ring, a point a second, where
a ramp shows as a ramp; an hour of the store's minutes would draw it as a straight line."""
DEFAULT_POINTS: Final = 600
MAX_POINTS: Final = 5000
MAX_WINDOW_S: Final = 3650 * 86400.0
MAX_STORE_QUERIES: Final = 2
"""History queries reading the store at once (each a thread's CPU while it runs)."""
MAX_WAITING_QUERIES: Final = 8
INLINE_POINTS: Final = 1000
"""Up to this many points (the live 15 minutes) are merged on the event loop."""
KEY: Final = re.compile(r"^[A-Za-z0-9_]{1,64}$")


class HistorySource(Protocol):
    """The store's side (`gateway.store.EventStore`)."""

    @property
    def history_step_s(self) -> float: ...

    @property
    def history_days(self) -> float: ...

    async def history_window(
        self, drive: str, since: float, until: float, max_points: int
    ) -> tuple[float, list[tuple[float, dict[str, Value]]]]: ...


T = TypeVar("T")


class StoreQueries:
    """At most `running` history queries on the store at once, `waiting` more in line; the
    next is refused (503) rather than queued without bound."""

    def __init__(self, running: int = MAX_STORE_QUERIES, waiting: int = MAX_WAITING_QUERIES):
        self._slots = asyncio.Semaphore(running)
        self._waiting = 0
        self.max_waiting = waiting
        self.refused = 0

    @contextlib.asynccontextmanager
    async def turn(self) -> AsyncIterator[None]:
        if self._slots.locked() and self._waiting >= self.max_waiting:
            self.refused += 1
            busy = http_error(503, "too many history queries at once: try again shortly")
            busy.headers["Retry-After"] = "1"
            raise busy
        self._waiting += 1
        try:
            await self._slots.acquire()
        finally:
            self._waiting -= 1
        try:
            yield
        finally:
            self._slots.release()


HISTORY_SOURCE: Final = web.AppKey("history_source", HistorySource)
STORE_QUERIES: Final = web.AppKey("history_store_queries", StoreQueries)

HISTORY: Final = """
<h1>History <span id="live" class="live">loading…</span></h1>
<form id="history-filters" class="filters">
<label>Drive <select id="h-drive"></select></label>
<label>Window <select id="h-window">
<option value="15m" selected>15 minutes (live)</option><option value="1h">1 hour</option>
<option value="6h">6 hours</option><option value="24h">24 hours</option>
<option value="7d">7 days</option></select></label>
<button type="button" id="h-reset" disabled>Whole window</button>
<a id="h-csv" class="button" href="#" download>Download CSV</a>
<span id="h-count" class="muted"></span>
</form>
<section>
<h2>Values</h2>
<div id="h-keys" class="keys"></div>
</section>
<section>
<p class="muted">Drag across a chart to zoom in; the CSV file holds what the charts show.</p>
<div id="h-charts" class="charts"></div>
</section>
"""


def add_routes(app: web.Application, source: HistorySource | None) -> None:
    """The page and the API, on `app` (before it starts); without a store, the live 15
    minutes only."""
    if source is not None:
        app[HISTORY_SOURCE] = source
    app[STORE_QUERIES] = StoreQueries()
    app.add_routes(
        [
            web.get("/history", history_page),
            web.get("/api/drives/{name}/history", drive_history),
        ]
    )


async def history_page(request: web.Request) -> web.StreamResponse:
    console = request.app[CONSOLE]
    drives = list(console.live.drives)
    drive = request.query.get("drive") or (drives[0] if drives else "")
    data = {"page": "history", "drives": ",".join(drives), "drive": drive}
    return html_page(request, "History", HISTORY, data, scripts=("uPlot.iife.min.js", "history.js"))


async def drive_history(request: web.Request) -> web.StreamResponse:
    console = request.app[CONSOLE]
    name = drive_name(request)
    since, until = _window(request)
    max_points = _points(request)
    live_from = time.time() - HISTORY_S
    source = request.app.get(HISTORY_SOURCE)
    if since >= live_from - 1.0 or source is None:
        points = console.live.recent_values(name, since, until)
        origin, step_s = "live", 1.0
    else:
        try:
            async with request.app[STORE_QUERIES].turn():
                step_s, points = await source.history_window(name, since, until, max_points)
        except StoreError as exc:
            raise http_error(409, f"the history cannot be read now: {exc}") from None
        origin = "store"
    now = values(console.live.telemetry(name))
    # A week of a drive's minutes is ten thousand points: merged off the event loop (the
    # buses' loop), like the store's own reading.
    numbers, texts = await _off_the_loop(points, _available, points, now)
    keys = _keys(request, numbers + texts, name)
    shown = await _off_the_loop(points, series, points, keys, step_s, max_points)
    if request.query.get("format") == "csv":
        response = web.Response(text=history_csv(shown), content_type="text/csv", charset="utf-8")
        filename = f"{name}-{iso_time(since)[:16].replace(':', '')}.csv"
        response.headers["Content-Disposition"] = f'attachment; filename="{filename}"'
        return response
    return web.json_response(
        {
            "drive": name,
            "source": origin,
            "step_s": shown.step_s,
            "since": iso_time(since),
            "until": iso_time(until),
            "history_days": None if source is None else source.history_days,
            "available": numbers,
            "text_values": texts,
            "keys": ["time", *shown.keys],
            "columns": [shown.times, *shown.columns],
        }
    )


async def _off_the_loop(points: Sequence[object], work: Callable[..., T], *args: Any) -> T:
    """`work(*args)` in a thread when there are many points; at once when there are few."""
    if len(points) <= INLINE_POINTS:
        return work(*args)
    return await asyncio.to_thread(work, *args)


def history_csv(shown: Series) -> str:
    """time (ISO 8601, UTC), then one column per value: what the chart shows."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(["time", *shown.keys])
    for index, at in enumerate(shown.times):
        row = [_cell(column[index]) for column in shown.columns]
        writer.writerow([iso_time(at), *row])
    return out.getvalue()


def _cell(value: Value | None) -> str:
    if value is None:
        return ""
    # Numbers as numbers (a negative one too); a text value quoted if it reads as a formula.
    return text_cell(value) if isinstance(value, str) else f"{value:g}"


def _points(request: web.Request) -> int:
    text = request.query.get("points")
    if text is None:
        return DEFAULT_POINTS
    try:
        points = int(text)
    except ValueError:
        points = 0
    if not 1 <= points <= MAX_POINTS:
        raise http_error(400, f"points: a whole number, 1 to {MAX_POINTS} (a chart's width)")
    return points


def _window(request: web.Request) -> tuple[float, float]:
    query = request.query
    now = time.time()
    until = time_query(request, "until") or now
    since = time_query(request, "since")
    if since is None:
        window = query.get("window", DEFAULT_WINDOW)
        if window not in WINDOWS:
            raise http_error(400, f"window: one of {', '.join(WINDOWS)} (or since= and until=)")
        since = until - WINDOWS[window]
    if since >= until:
        raise http_error(400, "since: must be before until")
    if until - since > MAX_WINDOW_S:
        raise http_error(400, "since: a window of 10 years at most")
    return since, until


def _available(
    points: Sequence[tuple[float, dict[str, Value]]], now: dict[str, Value]
) -> tuple[list[str], list[str]]:
    """The values this drive has (now, or in the window) by name: numbers, and texts."""
    found: dict[str, bool] = {k: isinstance(v, str) for k, v in now.items()}
    for _, point in points:
        for key, value in point.items():
            found.setdefault(key, isinstance(value, str))
    return sorted(k for k, text in found.items() if not text), sorted(
        k for k, text in found.items() if text
    )


def _keys(request: web.Request, available: list[str], drive: str) -> list[str]:
    asked = [k.strip() for v in request.query.getall("keys", []) for k in v.split(",")]
    asked = [k for k in asked if k]
    if not asked:
        return available
    for key in asked:
        if not KEY.match(key):
            raise http_error(400, f"keys: {key[:64]!r} is not a value's name (letters, digits, _)")
        if key not in available:
            known = ", ".join(available) or "none yet"
            raise http_error(400, f"keys: {drive} has no value {key!r} (it has: {known})")
    return list(dict.fromkeys(asked))
