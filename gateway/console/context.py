"""What every handler of the console reaches: the parts (`Console`, at `CONSOLE` on the
application), who is asking (`IDENTITY`, set by the guard), and the steps handlers share: an
HTML page, a drive named in the path, a JSON body, a drive operation's error as an HTTP one."""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable, Sequence
from dataclasses import replace
from typing import Any, Final

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
from gateway.console.diagnostics import MqttSession, OpcUaSessions, TcpClients
from gateway.console.events import Category, EventStore, GatewayEvent, audit_text
from gateway.console.live import LiveState
from gateway.console.log_tail import LogTail
from gateway.console.operations import DriveOperations
from gateway.console.replies import http_error, json_body
from gateway.console.traffic import TrafficMonitor
from gateway.errors import OperationError

MAX_JSON: Final = 16 * 1024
IDENTITY: Final = web.RequestKey("identity", Identity)
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
        opcua: OpcUaSessions | None = None,
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
        self.opcua = opcua
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


def drive_json(console: Console, name: str) -> dict[str, Any]:
    return {**console.live.drive_view(name), "telemetry": console.live.telemetry(name)}


async def read_json(request: web.Request) -> dict[str, Any]:
    return await json_body(request, MAX_JSON)


async def operation(work: Awaitable[Any]) -> Any:
    try:
        return await work
    except OperationError as exc:
        raise http_error(exc.status, str(exc)) from None


def drive_name(request: web.Request) -> str:
    name = request.match_info["name"]
    if name not in request.app[CONSOLE].live.drives:
        raise http_error(404, f"no drive named {name!r}")
    return name
