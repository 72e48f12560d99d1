"""The console's guard, which every request passes before its handler: it finds who is asking
(session cookie, API token, or anonymous when allowed), refuses what they may not do, checks the
origin of every write and the CSRF token of every write made with a session cookie, and adds the
security headers. Handlers only answer."""

from __future__ import annotations

import hmac
from typing import Final
from urllib.parse import quote

from aiohttp import web

from gateway.console.auth import SESSION_COOKIE, Via
from gateway.console.context import CONSOLE, IDENTITY, Console, Handler
from gateway.console.replies import http_error

SECURITY_HEADERS: Final = {
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

_OPEN_PATHS: Final = ("/login", "/api/login", "/static/", "/favicon.ico")


@web.middleware
async def guard(request: web.Request, handler: Handler) -> web.StreamResponse:
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
    for name, value in SECURITY_HEADERS.items():
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
