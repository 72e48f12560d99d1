"""Logging in and out of the console, and the session's own view of who is logged in.

POST /api/login     {"name", "password"}: a session cookie and its CSRF token; failed
                    logins are throttled per name and address, and each is an audit event
POST /api/logout
GET  /api/session   who is asking, by which means, and what they may do
"""

from __future__ import annotations

import asyncio
import logging

from aiohttp import web

from gateway.console.auth import MAX_NAME_LENGTH, SESSION_COOKIE, Via
from gateway.console.context import CONSOLE, IDENTITY, read_json
from gateway.console.replies import http_error
from gateway.logs import repeated

log = logging.getLogger(__name__)


async def login(request: web.Request) -> web.StreamResponse:
    console = request.app[CONSOLE]
    body = await read_json(request)
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
