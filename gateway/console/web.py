"""The console's HTTP side on aiohttp: pages, the JSON API, the live streams, the static files.

Every request passes `_guard` first: it finds who is asking (session cookie, API token, or
anonymous when allowed), refuses what they may not do, checks the CSRF token of every write made
with a session cookie, and adds the security headers. Handlers only answer.

The JSON API (documented in the README's "Console" section) is what the pages use; the live
parts are server-sent events (`text/event-stream`), which browsers reconnect by themselves.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import json
import logging
import time
from collections.abc import Awaitable, Callable, Sequence
from dataclasses import replace
from importlib import resources
from typing import Any, Final
from urllib.parse import quote

from aiohttp import web

from gateway.console import pages
from gateway.console.auth import (
    ANONYMOUS,
    MAX_NAME_LENGTH,
    SESSION_COOKIE,
    Identity,
    LoginCounts,
    LoginThrottle,
    Sessions,
    Users,
    Via,
)
from gateway.console.bad_requests import BadRequests
from gateway.console.deadlines import mark_requests
from gateway.console.diagnostics import MqttSession, TcpClients, tcp_clients_json
from gateway.console.events import (
    Category,
    EventQuery,
    EventStore,
    GatewayEvent,
    audit_text,
    events_csv,
)
from gateway.console.live import LiveState
from gateway.console.log_tail import MAX_LINES as LOG_LINES
from gateway.console.log_tail import LogTail
from gateway.console.operations import (
    REGISTER_BLOCKS,
    DriveOperations,
)
from gateway.console.replies import (
    MAX_EVENTS,
    http_error,
    json_body,
    query_limit,
    time_query,
)
from gateway.console.traffic import TrafficMonitor
from gateway.errors import OperationError
from gateway.logs import repeated
from gateway.poller.drive_state import iso_time

log = logging.getLogger(__name__)

LIVE_PERIOD_S: Final = 0.5
"""The overview and a drive's page are pushed this often: live within a second."""
HEARTBEAT_S: Final = 15.0
RECENT_BATCH: Final = 100
"""Transactions kept that a new monitor gets between two turns of the event loop."""
MAX_JSON: Final = 16 * 1024
MAX_CSV_EVENTS: Final = 20000
"""A file of events may hold a shift's worth; a page shows fewer."""
IDENTITY: Final = web.RequestKey("identity", Identity)
_SECURITY_HEADERS: Final = {
    # No inline script or style, nothing from elsewhere: a plant network is often offline, and
    # an injected script has nowhere to come from.
    "Content-Security-Policy": (
        "default-src 'self'; img-src 'self' data:; style-src 'self'; script-src 'self'; "
        "frame-ancestors 'none'; base-uri 'none'; form-action 'self'"
    ),
    "X-Content-Type-Options": "nosniff",
    "X-Frame-Options": "DENY",
    "Referrer-Policy": "no-referrer",
}
Handler = Callable[[web.Request], Awaitable[web.StreamResponse]]


class Console:
    """The parts the handlers use; the application passes them in (`ConsoleFeature`)."""

    def __init__(
        self,
        *,
        users: Users,
        anonymous_view: bool,
        commands_enabled: bool,
        secure_cookies: bool,
        live: LiveState,
        operations: DriveOperations,
        traffic: TrafficMonitor,
        events: EventStore,
        tcp: TcpClients | None = None,
        mqtt: MqttSession | None = None,
        log: LogTail | None = None,
        configuration: Callable[[], dict[str, Any]] | None = None,
    ) -> None:
        self.users = users
        self.anonymous_view = anonymous_view
        self.commands_enabled = commands_enabled
        self.secure_cookies = secure_cookies
        self.live = live
        self.operations = operations
        self.traffic = traffic
        self.events = events
        self.tcp = tcp
        self.mqtt = mqtt
        self.log = log if log is not None else LogTail()
        self.configuration = configuration
        self.sessions = Sessions()
        self.throttle = LoginThrottle()
        self.logins = LoginCounts()
        self.closing = asyncio.Event()

    def identify(self, request: web.Request) -> Identity | None:
        authorization = request.headers.get("Authorization", "")
        if authorization.startswith("Bearer "):
            user = self.users.by_token(authorization.removeprefix("Bearer ").strip())
            return None if user is None else replace(user, address=request.remote)
        key = request.cookies.get(SESSION_COOKIE)
        if key:
            session = self.sessions.get(key)
            # A user removed from the config (or given another role) is gone at once.
            if session is not None and self.users.role_of(session.user) is session.role:
                return Identity(session.user, session.role, Via.SESSION, request.remote)
        return ANONYMOUS if self.anonymous_view else None

    def refused_write(self, who: Identity, request: web.Request, reason: str) -> None:
        """A write refused before it could reach a drive: an audit event when somebody logged
        in asked for it (anonymous refusals are not: nobody to name, and free to repeat)."""
        if who.via is Via.ANONYMOUS:
            return
        name = request.match_info.get("name")
        drive = self.live.drives.get(name) if name is not None else None
        configuration = request.path.endswith("/parameter")
        event = GatewayEvent(
            "write",
            f"{request.method} {request.path}",
            drive=name if drive is not None else None,
            bus=drive.bus if drive is not None else None,
            who=who.client,
            result=f"refused: {reason}",
            address=who.address,
            category=Category.CONFIGURATION if configuration else Category.CONTROL,
        )
        self.events.record(event)

    def audit(self, kind: str, user: str, address: str, result: str) -> None:
        """A login, failed login or logout: into the events (the store, MQTT), never with the
        password. The name as typed, cut short: it may be anything."""
        user = user[:MAX_NAME_LENGTH]
        text = audit_text(kind, {"user": user, "address": address})
        self.events.record(
            GatewayEvent(
                kind,
                text,
                who=user,
                result=result,
                address=address,
                category=Category.AUTHENTICATION,
            )
        )


CONSOLE: Final = web.AppKey("console", Console)


def build_app(console: Console, bad: BadRequests) -> web.Application:
    """The console's application; `bad` counts and logs what is refused for its content."""
    middlewares = [mark_requests, bad.middleware, _guard]
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


# -- the guard ------------------------------------------------------------------------------

_OPEN_PATHS: Final = ("/login", "/api/login", "/static/", "/favicon.ico")


@web.middleware
async def _guard(request: web.Request, handler: Handler) -> web.StreamResponse:
    console = request.app[CONSOLE]
    try:
        response = await _guarded(console, request, handler)
    except web.HTTPException as exc:
        _secure(request, exc)
        raise
    _secure(request, response)
    return response


def _secure(request: web.Request, response: web.StreamResponse) -> None:
    if response.prepared:  # a stream: its headers went out with them already
        return
    for name, value in _SECURITY_HEADERS.items():
        response.headers.setdefault(name, value)
    if not request.path.startswith("/static/"):
        response.headers.setdefault("Cache-Control", "no-store")


async def _guarded(console: Console, request: web.Request, handler: Handler) -> web.StreamResponse:
    path = request.path
    if request.method not in ("GET", "HEAD") and not _same_origin(request):
        raise http_error(403, "cross-site request refused")
    if path.startswith(_OPEN_PATHS):
        return await handler(request)
    who = console.identify(request)
    if who is None:
        if path.startswith("/api/"):
            raise http_error(401, "log in, or send an API token (Authorization: Bearer TOKEN)")
        raise web.HTTPFound(f"/login?next={quote(path)}")
    if request.method not in ("GET", "HEAD") and path != "/api/logout":
        refusal = None
        if not who.may_write:
            refusal = f"{who.name} ({who.role}) may not make changes: operators only"
        elif who.via is Via.SESSION and not _csrf_ok(console, request):
            refusal = "missing or wrong CSRF token (X-CSRF-Token)"
        if refusal is not None:
            console.refused_write(who, request, refusal)
            raise http_error(403, refusal)
    request[IDENTITY] = who
    return await handler(request)


def _same_origin(request: web.Request) -> bool:
    """A browser names the page a write comes from: it must be one of ours."""
    origin = request.headers.get("Origin")
    if origin is None:
        return True  # not a browser (curl, scripts): the token or CSRF check decides
    return origin.split("://", 1)[-1] == request.host


def _csrf_ok(console: Console, request: web.Request) -> bool:
    session = console.sessions.get(request.cookies.get(SESSION_COOKIE, ""))
    sent = request.headers.get("X-CSRF-Token", "")
    return session is not None and bool(sent) and hmac.compare_digest(sent, session.csrf_token)


# -- pages ----------------------------------------------------------------------------------


def html_page(
    request: web.Request,
    title: str,
    body: str,
    data: dict[str, str],
    scripts: Sequence[str] | None = None,
) -> web.Response:
    """A page; `scripts`: what it loads before console.js (uPlot for a drive's page)."""
    console = request.app[CONSOLE]
    who = request.get(IDENTITY)
    if scripts is None:
        scripts = ["uPlot.iife.min.js"] if data.get("page") == "drive" else ()
    html = pages.page(
        title,
        body,
        who=who,
        buses=list(console.live.buses),
        data={**data, "commands": "on" if console.commands_enabled else "off"},
        scripts=scripts,
    )
    return web.Response(text=html, content_type="text/html")


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


# -- login ----------------------------------------------------------------------------------


async def login(request: web.Request) -> web.StreamResponse:
    console = request.app[CONSOLE]
    body = await _json_body(request)
    name, password = str(body.get("name", "")), str(body.get("password", ""))
    address = request.remote or "?"
    throttle = console.throttle
    wait = throttle.retry_after(name, address)
    if wait > 0:
        console.logins.throttled += 1
        retry = max(1, round(wait))
        if throttle.refused(name, address):  # the first refusal is reported, the rest counted
            console.audit("login_failed", name, address, f"throttled: retry in {retry} s")
        refused = http_error(429, f"too many failed logins: try again in {retry} s")
        refused.headers["Retry-After"] = str(retry)
        raise refused
    # scrypt takes tens of milliseconds of CPU: in a thread, so the bus never waits for it.
    role = await asyncio.to_thread(console.users.check_password, name, password)
    if role is None:
        throttle.failed(name, address)
        console.logins.failed += 1
        log.warning(
            "console: failed login for %r from %s",
            name[:MAX_NAME_LENGTH],
            address,
            extra=repeated("console-login-failed"),  # each is an audit event; the log sums up
        )
        console.audit("login_failed", name, address, "wrong name or password")
        raise http_error(401, "wrong name or password")
    throttle.succeeded(name, address)
    console.logins.ok += 1
    key, session = console.sessions.open(name, role)
    log.info("console: %s logged in from %s", name, address)
    console.audit("login", name, address, "ok")
    response = web.json_response(
        {"ok": True, "user": name, "role": str(role), "csrf_token": session.csrf_token}
    )
    response.set_cookie(
        SESSION_COOKIE,
        key,
        httponly=True,
        samesite="Strict",
        secure=console.secure_cookies,
        path="/",
    )
    return response


async def logout(request: web.Request) -> web.StreamResponse:
    console = request.app[CONSOLE]
    key = request.cookies.get(SESSION_COOKIE, "")
    session = console.sessions.get(key) if key else None
    if session is not None:
        console.sessions.close(key)
        log.info("console: %s logged out from %s", session.user, request.remote)
        console.audit("logout", session.user, request.remote or "?", "ok")
    response = web.json_response({"ok": True})
    response.del_cookie(SESSION_COOKIE, path="/")
    return response


async def session_info(request: web.Request) -> web.StreamResponse:
    console = request.app[CONSOLE]
    who = request[IDENTITY]
    csrf = None
    if who.via is Via.SESSION:
        session = console.sessions.get(request.cookies.get(SESSION_COOKIE, ""))
        csrf = session.csrf_token if session else None
    return web.json_response(
        {
            "user": who.name,
            "role": str(who.role),
            "via": str(who.via),
            "csrf_token": csrf,
            "may_write": who.may_write and console.commands_enabled,
            "may_configure": who.may_configure,
            "commands_enabled": console.commands_enabled,
        }
    )


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
    clients and the MQTT session: all read from what their owners keep, nothing waits."""
    console = request.app[CONSOLE]
    return web.json_response(
        {
            "time": iso_time(time.time()),
            "buses": console.live.line_counters(),
            "modbus_tcp": None
            if console.tcp is None
            else {"clients": tcp_clients_json(console.tcp)},
            "mqtt": None if console.mqtt is None else console.mqtt.status().to_json(),
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
    return web.json_response(_drive_json(request.app[CONSOLE], drive_name(request)))


def _drive_json(console: Console, name: str) -> dict[str, Any]:
    return {**console.live.drive_view(name), "telemetry": console.live.telemetry(name)}


async def drive_chart(request: web.Request) -> web.StreamResponse:
    return web.json_response(request.app[CONSOLE].live.chart(drive_name(request)))


async def drive_faults(request: web.Request) -> web.StreamResponse:
    console = request.app[CONSOLE]
    name = drive_name(request)
    history = await _operation(console.operations.fault_history(request[IDENTITY], name))
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
        found = await _operation(console.operations.find_parameters(request[IDENTITY], name, text))
        return web.json_response({"find": text, "groups": groups, "parameters": found})
    group = request.query.get("group", groups[0])
    found = await _operation(console.operations.parameter_group(request[IDENTITY], name, group))
    return web.json_response({"group": group, "groups": groups, "parameters": found})


# -- writes ---------------------------------------------------------------------------------


async def drive_command(request: web.Request) -> web.StreamResponse:
    console = request.app[CONSOLE]
    body = await _json_body(request)
    command = str(body.get("command", ""))
    result = await _operation(
        console.operations.command(request[IDENTITY], drive_name(request), command)
    )
    return web.json_response(result)


async def drive_frequency(request: web.Request) -> web.StreamResponse:
    console = request.app[CONSOLE]
    body = await _json_body(request)
    hz = body.get("hz")
    if not isinstance(hz, int | float) or isinstance(hz, bool):
        raise http_error(400, 'hz: a number of hertz, e.g. {"hz": 25.0}')
    result = await _operation(
        console.operations.set_frequency(request[IDENTITY], drive_name(request), float(hz))
    )
    return web.json_response(result)


async def drive_parameter(request: web.Request) -> web.StreamResponse:
    console = request.app[CONSOLE]
    body = await _json_body(request)
    name, value, ram = body.get("name"), body.get("value"), body.get("ram", False)
    if not isinstance(name, str) or not isinstance(value, str | int | float):
        example = '{"name": "P00.11", "value": "10.0", "ram": true}'
        raise http_error(400, f"name and value: e.g. {example}")
    if not isinstance(ram, bool):
        raise http_error(400, "ram: true or false")
    result = await _operation(
        console.operations.write_parameter(
            request[IDENTITY], drive_name(request), name, str(value), ram
        )
    )
    return web.json_response(result)


# -- live streams ---------------------------------------------------------------------------


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
                await _send_event(response, "drive", _drive_json(console, drive))
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
    for name, value in _SECURITY_HEADERS.items():
        response.headers[name] = value
    await response.prepare(request)
    return response


async def _send_event(response: web.StreamResponse, event: str, data: Any) -> None:
    await response.write(f"event: {event}\ndata: {json.dumps(data)}\n\n".encode())


async def _wait(console: Console, seconds: float) -> None:
    with contextlib.suppress(TimeoutError):
        await asyncio.wait_for(console.closing.wait(), seconds)


# -- helpers --------------------------------------------------------------------------------


async def _json_body(request: web.Request) -> dict[str, Any]:
    return await json_body(request, MAX_JSON)


async def _operation(work: Awaitable[Any]) -> Any:
    try:
        return await work
    except OperationError as exc:
        raise http_error(exc.status, str(exc)) from None


def drive_name(request: web.Request) -> str:
    name = request.match_info["name"]
    if name not in request.app[CONSOLE].live.drives:
        raise http_error(404, f"no drive named {name!r}")
    return name
