"""The console's HTTP side on aiohttp: its routes, the pages, the JSON API's reads and writes,
the static files.

Every request passes the guard (`guard`) first: it finds who is asking, refuses what they may
not do and adds the security headers; handlers only answer, with what `context` gives them.
Logging in and out is `login`; the live parts are server-sent events (`streams`); the history
and configuration pages add their own routes (`history`, `configuration`).

The JSON API (documented in the README's "Console" section) is what the pages use.
"""

from __future__ import annotations

import time
from importlib import resources
from typing import Final

from aiohttp import web

from gateway.console import pages
from gateway.console.bad_requests import BadRequests
from gateway.console.context import (
    CONSOLE,
    IDENTITY,
    MAX_JSON,
    Console,
    drive_json,
    drive_name,
    html_page,
    operation,
    read_json,
)
from gateway.console.deadlines import mark_requests
from gateway.console.diagnostics import tcp_clients_json
from gateway.console.events import EventQuery, events_csv
from gateway.console.guard import guard
from gateway.console.log_tail import MAX_LINES as LOG_LINES
from gateway.console.login import login, logout, session_info
from gateway.console.operations import REGISTER_BLOCKS
from gateway.console.replies import MAX_EVENTS, http_error, query_limit, time_query
from gateway.console.streams import live_stream, traffic_stream
from gateway.poller.drive_state import iso_time

MAX_CSV_EVENTS: Final = 20000
"""A file of events may hold a shift's worth; a page shows fewer."""


def build_app(console: Console, bad: BadRequests) -> web.Application:
    """The console's application; `bad` counts and logs what is refused for its content."""
    middlewares = [mark_requests, bad.middleware, guard]
    app = web.Application(middlewares=middlewares, client_max_size=MAX_JSON)
    app[CONSOLE] = console
    static = resources.files("gateway.console").joinpath("static")
    routes = [
        web.get("/", overview_page),
        web.get("/drives/{name}", drive_page),
        web.get("/events", events_page),
        web.get("/diagnostics", diagnostics_page),
        web.get("/monitor", monitor_page),
        web.get("/monitor/{bus}", monitor_page),
        web.get("/login", login_page),
        web.post("/api/login", login),
        web.post("/api/logout", logout),
        web.get("/api/session", session_info),
        web.get("/api/overview", overview),
        web.get("/api/live", live_stream),
        web.get("/api/events", events),
        web.get("/api/diagnostics", diagnostics),
        web.get("/api/log", recent_log),
        web.get("/api/config", running_configuration),
        web.get("/api/drives/{name}", drive_detail),
        web.get("/api/drives/{name}/chart", drive_chart),
        web.get("/api/drives/{name}/faults", drive_faults),
        web.get("/api/drives/{name}/parameters", drive_parameters),
        web.post("/api/drives/{name}/command", drive_command),
        web.post("/api/drives/{name}/frequency", drive_frequency),
        web.post("/api/drives/{name}/parameter", drive_parameter),
        web.get("/api/buses/{bus}/traffic", traffic_stream),
        web.static("/static", str(static), append_version=False),
        web.get("/favicon.ico", favicon),
    ]
    app.add_routes(routes)
    return app


FAVICON: Final = resources.files("gateway.console").joinpath("static", "favicon.ico")


async def favicon(request: web.Request) -> web.StreamResponse:
    """Where every browser asks for a site's icon, whatever the page links: no 404 per page."""
    response = web.Response(body=FAVICON.read_bytes(), content_type="image/x-icon")
    response.headers["Cache-Control"] = "max-age=86400"
    return response


# -- pages ----------------------------------------------------------------------------------


async def overview_page(request: web.Request) -> web.StreamResponse:
    return html_page(request, "Overview", pages.OVERVIEW, {"page": "overview"})


async def drive_page(request: web.Request) -> web.StreamResponse:
    name = request.match_info["name"]
    if name not in request.app[CONSOLE].live.drives:
        raise web.HTTPNotFound(text=f"no drive named {name}")
    groups = request.app[CONSOLE].operations.parameter_groups(name)
    data = {"page": "drive", "drive": name, "groups": ",".join((*groups, *REGISTER_BLOCKS))}
    return html_page(request, name, pages.DRIVE, data)


async def monitor_page(request: web.Request) -> web.StreamResponse:
    buses = list(request.app[CONSOLE].live.buses)
    bus = request.match_info.get("bus", buses[0])
    if bus not in buses:
        raise web.HTTPNotFound(text=f"no bus named {bus}")
    return html_page(request, f"Monitor {bus}", pages.MONITOR, {"page": "monitor", "bus": bus})


async def events_page(request: web.Request) -> web.StreamResponse:
    drives = ",".join(request.app[CONSOLE].live.drives)
    return html_page(request, "Events", pages.EVENTS, {"page": "events", "drives": drives})


async def diagnostics_page(request: web.Request) -> web.StreamResponse:
    return html_page(request, "Diagnostics", pages.DIAGNOSTICS, {"page": "diagnostics"})


async def login_page(request: web.Request) -> web.StreamResponse:
    return html_page(request, "Log in", pages.LOGIN, {"page": "login"})


# -- reads ----------------------------------------------------------------------------------


async def overview(request: web.Request) -> web.StreamResponse:
    return web.json_response(request.app[CONSOLE].live.overview())


async def events(request: web.Request) -> web.StreamResponse:
    """The events, newest first: `?drive=&kind=&since=&until=&limit=`, `&format=csv` for a file."""
    console = request.app[CONSOLE]
    as_csv = request.query.get("format") == "csv"
    limit = query_limit(request, maximum=MAX_CSV_EVENTS if as_csv else MAX_EVENTS)
    found = await console.events.history(_event_query(console, request), limit)
    if not as_csv:
        return web.json_response({"events": [e.to_json() for e in found]})
    response = web.Response(text=events_csv(found), content_type="text/csv", charset="utf-8")
    response.headers["Content-Disposition"] = 'attachment; filename="events.csv"'
    return response


def _event_query(console: Console, request: web.Request) -> EventQuery:
    query = request.query
    drive = query.get("drive") or None
    if drive is not None and drive not in console.live.drives:
        raise http_error(404, f"drive: no drive named {drive!r}")
    kinds = frozenset(k.strip() for value in query.getall("kind", []) for k in value.split(","))
    return EventQuery(
        drive, kinds - {""}, time_query(request, "since"), time_query(request, "until")
    )


async def diagnostics(request: web.Request) -> web.StreamResponse:
    """The line's counters per bus and drive (since start, last minute), the Modbus-TCP
    clients, the MQTT session and the OPC UA sessions: all read from what their owners keep,
    nothing waits."""
    console = request.app[CONSOLE]
    return web.json_response(
        {
            "time": iso_time(time.time()),
            "buses": console.live.line_counters(),
            "modbus_tcp": None
            if console.tcp is None
            else {"clients": tcp_clients_json(console.tcp)},
            "mqtt": None if console.mqtt is None else console.mqtt.status().to_json(),
            "opcua": None if console.opcua is None else {"sessions": console.opcua.sessions()},
        }
    )


async def recent_log(request: web.Request) -> web.StreamResponse:
    """The log's recent lines (`?level=warning`, default info; `?limit=N`), oldest first."""
    console = request.app[CONSOLE]
    level = request.query.get("level", "info")
    try:
        lines = console.log.lines(level, query_limit(request, "limit", 200, LOG_LINES))
    except ValueError as exc:
        raise http_error(400, str(exc)) from None
    return web.json_response({"level": level, "lines": lines})


async def running_configuration(request: web.Request) -> web.StreamResponse:
    """The configuration the gateway runs on now, secrets masked; operators only (it maps the
    plant's network: addresses, ports, users)."""
    console = request.app[CONSOLE]
    who = console.identify(request)
    if who is None or not who.may_write:
        raise http_error(403, "the running configuration is for operators")
    if console.configuration is None:
        raise http_error(404, "no configuration to show")
    return web.json_response({"configuration": console.configuration()})


async def drive_detail(request: web.Request) -> web.StreamResponse:
    return web.json_response(drive_json(request.app[CONSOLE], drive_name(request)))


async def drive_chart(request: web.Request) -> web.StreamResponse:
    return web.json_response(request.app[CONSOLE].live.chart(drive_name(request)))


async def drive_faults(request: web.Request) -> web.StreamResponse:
    console = request.app[CONSOLE]
    name = drive_name(request)
    history = await operation(console.operations.fault_history(request[IDENTITY], name))
    found = await console.events.history(EventQuery(drive=name), query_limit(request))
    recorded = await console.events.recorded_faults(name, query_limit(request))
    return web.json_response(
        {
            "fault_history": history,
            "recorded_faults": recorded,
            "events": [e.to_json() for e in found if e.drive == name],
        }
    )


async def drive_parameters(request: web.Request) -> web.StreamResponse:
    console = request.app[CONSOLE]
    name = drive_name(request)
    groups = [*console.operations.parameter_groups(name), *REGISTER_BLOCKS]
    text = request.query.get("find")
    if text is not None:
        found = await operation(console.operations.find_parameters(request[IDENTITY], name, text))
        return web.json_response({"find": text, "groups": groups, "parameters": found})
    group = request.query.get("group", groups[0])
    found = await operation(console.operations.parameter_group(request[IDENTITY], name, group))
    return web.json_response({"group": group, "groups": groups, "parameters": found})


# -- writes ---------------------------------------------------------------------------------


async def drive_command(request: web.Request) -> web.StreamResponse:
    console = request.app[CONSOLE]
    body = await read_json(request)
    command = str(body.get("command", ""))
    result = await operation(
        console.operations.command(request[IDENTITY], drive_name(request), command)
    )
    return web.json_response(result)


async def drive_frequency(request: web.Request) -> web.StreamResponse:
    console = request.app[CONSOLE]
    body = await read_json(request)
    hz = body.get("hz")
    if not isinstance(hz, int | float) or isinstance(hz, bool):
        raise http_error(400, 'hz: a number of hertz, e.g. {"hz": 25.0}')
    result = await operation(
        console.operations.set_frequency(request[IDENTITY], drive_name(request), float(hz))
    )
    return web.json_response(result)


async def drive_parameter(request: web.Request) -> web.StreamResponse:
    console = request.app[CONSOLE]
    body = await read_json(request)
    name, value, ram = body.get("name"), body.get("value"), body.get("ram", False)
    if not isinstance(name, str) or not isinstance(value, str | int | float):
        example = '{"name": "P00.11", "value": "10.0", "ram": true}'
        raise http_error(400, f"name and value: e.g. {example}")
    if not isinstance(ram, bool):
        raise http_error(400, "ram: true or false")
    result = await operation(
        console.operations.write_parameter(
            request[IDENTITY], drive_name(request), name, str(value), ram
        )
    )
    return web.json_response(result)
