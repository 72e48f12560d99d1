"""The configuration page and its JSON API: for the admin role only (`ConfigEditor` does the work).

    GET  /configuration                         the page: edit, check, apply, versions, rollback
    GET  /api/config/file                       the file's text, secrets as "***N", its `base`
    POST /api/config/check      {"text","base"} problems (key, reason), warnings, what would
                                                change now and what waits for a restart
    POST /api/config/apply      {"text","note","base"}  kept as a new version, written, reloaded
    GET  /api/config/versions                   every version kept, newest first, with its diff
    GET  /api/config/versions/{id}              one version's text
    POST /api/config/versions/{id}/rollback     that version applied again (a new version)

Operators and viewers are refused (403), and a refused change by somebody logged in is an audit
event like an applied one or a rollback (`config_changed`, category configuration). Writes pass
the console's guard first (CSRF token, same origin).
"""

from __future__ import annotations

import json
from collections.abc import Awaitable
from html import escape
from typing import Any, Final, TypeVar

from aiohttp import web

from gateway.console.auth import Identity
from gateway.console.config_editor import ConfigEditor
from gateway.console.context import CONSOLE, IDENTITY, Console, html_page
from gateway.console.events import Category, GatewayEvent
from gateway.console.replies import http_error, json_body, status_class
from gateway.errors import EditRefused

T = TypeVar("T")
EDITOR: Final = web.AppKey("config_editor", ConfigEditor)
MAX_NOTE: Final = 200
MAX_BODY: Final = 512 * 1024
"""A configuration's text is bigger than the console's other requests."""

PAGE: Final = """
<h1>Configuration <span id="live" class="live">loading…</span></h1>
<p id="c-path" class="muted"></p>
<section>
<h2>Edit</h2>
<p class="muted">Secrets show as "***1", "***2"...: leave them so to keep them. Check says
what applying would change now and what waits for a restart; Apply keeps this as a new
version, writes the file and reloads it live.</p>
<textarea id="c-text" class="mono config" spellcheck="false" autocomplete="off"></textarea>
<form id="c-form" class="filters">
<label>Note <input id="c-note" maxlength="200" placeholder="why (kept with the version)"></label>
<button type="button" id="c-check">Check</button>
<button type="button" id="c-apply">Apply</button>
<button type="button" id="c-revert">Revert edits</button>
</form>
<div id="c-result" role="status"></div>
</section>
<section>
<h2>Versions</h2>
<div class="scroll"><table id="c-versions" class="grid cards small">
<thead><tr><th>Version</th><th>Time</th><th>Who</th><th>Note</th><th></th></tr></thead>
<tbody></tbody>
</table></div>
<pre id="c-diff" class="scroll mono diff" hidden></pre>
</section>
"""


def add_routes(app: web.Application, editor: ConfigEditor | None) -> None:
    """The page and the API on `app` (before it starts); without an editor (no configuration
    file: the gateway was started from code) the API says so."""
    if editor is not None:
        app[EDITOR] = editor
    app.add_routes(
        [
            web.get("/configuration", configuration_page),
            web.get("/api/config/file", config_file),
            web.post("/api/config/check", config_check),
            web.post("/api/config/apply", config_apply),
            web.get("/api/config/versions", config_versions),
            web.get("/api/config/versions/{number}", config_version),
            web.post("/api/config/versions/{number}/rollback", config_rollback),
        ]
    )


async def configuration_page(request: web.Request) -> web.StreamResponse:
    who: Identity = request[IDENTITY]
    if not who.may_configure:
        refused = html_page(request, "Configuration", _refused_page(who), {"page": "refused"})
        refused.set_status(403)
        return refused
    return html_page(
        request, "Configuration", PAGE, {"page": "configuration"}, scripts=("configuration.js",)
    )


async def config_file(request: web.Request) -> web.StreamResponse:
    editor = _editor(request, _admin(request))
    return web.json_response(await _done(editor.current()))


async def config_check(request: web.Request) -> web.StreamResponse:
    editor = _editor(request, _admin(request))
    body = await _body(request)
    text, base = _text(body), _base(body)
    checked = await _done(editor.check(text, base))
    return web.json_response(checked.to_json())


async def config_apply(request: web.Request) -> web.StreamResponse:
    console = request.app[CONSOLE]
    who = _admin(request, audit="apply the configuration")
    editor = _editor(request, who)
    body = await _body(request)
    text, note, base = _text(body), body.get("note", ""), _base(body)
    if not isinstance(note, str):
        raise http_error(400, 'note: a string, e.g. {"text": "buses: ...", "note": "why"}')
    try:
        result = await editor.apply(text, who.name, note[:MAX_NOTE], base)
    except EditRefused as exc:
        _audit(console, who, "configuration not applied", f"refused: {exc}")
        raise _refused(exc) from None
    _audit(console, who, _applied_text(result, note), "ok")
    return web.json_response({"ok": True, **result})


async def config_versions(request: web.Request) -> web.StreamResponse:
    editor = _editor(request, _admin(request))
    return web.json_response({"versions": await _done(editor.history())})


async def config_version(request: web.Request) -> web.StreamResponse:
    editor = _editor(request, _admin(request))
    return web.json_response(await _done(editor.version(_number(request))))


async def config_rollback(request: web.Request) -> web.StreamResponse:
    console = request.app[CONSOLE]
    who = _admin(request, audit="roll the configuration back")
    editor = _editor(request, who)
    number = _number(request)
    try:
        result = await editor.rollback(number, who.name)
    except EditRefused as exc:
        _audit(console, who, f"rollback to version {number} not applied", f"refused: {exc}")
        raise _refused(exc) from None
    text = f"configuration rolled back to version {number} (now version {result['version']})"
    _audit(console, who, _with_changes(text, result), "ok")
    return web.json_response({"ok": True, **result})


# -- helpers --------------------------------------------------------------------------------


def _refused_page(who: Identity) -> str:
    return (
        "<h1>Configuration</h1>"
        f'<p class="error">{escape(who.name)} ({escape(str(who.role))}) may not see or change '
        "the configuration: admins only.</p>"
    )


def _admin(request: web.Request, audit: str | None = None) -> Identity:
    """Who asks, if an admin; else 403 (and, for a change asked by somebody logged in, an
    audit event)."""
    who: Identity = request[IDENTITY]
    if who.may_configure:
        return who
    reason = f"{who.name} ({who.role}) may not see or change the configuration: admins only"
    if audit is not None and who.may_write:  # viewers can't get past the guard's own check
        _audit(request.app[CONSOLE], who, f"asked to {audit}", f"refused: {reason}")
    raise http_error(403, reason)


def _editor(request: web.Request, who: Identity) -> ConfigEditor:
    editor = request.app.get(EDITOR)
    if editor is None:
        raise http_error(404, "this gateway was started without a configuration file to edit")
    return editor


async def _done(work: Awaitable[T]) -> T:
    try:
        return await work
    except EditRefused as exc:
        raise _refused(exc) from None


async def _body(request: web.Request) -> dict[str, Any]:
    """The JSON body, up to `MAX_BODY` (the console's other requests are held to less)."""
    return await json_body(request, MAX_BODY)


def _text(body: dict[str, Any]) -> str:
    text = body.get("text")
    if not isinstance(text, str):
        raise http_error(400, 'text: the configuration as YAML text, e.g. {"text": "buses: ..."}')
    return text


def _base(body: dict[str, Any]) -> str | None:
    base = body.get("base")
    if base is not None and not isinstance(base, str):
        raise http_error(400, "base: the file's fingerprint as GET /api/config/file gave it")
    return base


def _number(request: web.Request) -> int:
    try:
        return int(request.match_info["number"])
    except ValueError:
        raise http_error(400, "version: a whole number") from None


def _refused(exc: EditRefused) -> web.HTTPException:
    """The reason, and for a text that doesn't check out each problem with its key."""
    body: dict[str, Any] = {}
    if exc.details is not None:
        body.update(exc.details)
    body.update({"ok": False, "error": str(exc)})
    return status_class(exc.status)(text=json.dumps(body), content_type="application/json")


def _applied_text(result: dict[str, object], note: str) -> str:
    text = f"configuration version {result['version']} applied"
    if note:
        text += f" ({note[:MAX_NOTE]})"
    return _with_changes(text, result)


def _with_changes(text: str, result: dict[str, object]) -> str:
    changed = result.get("changed") or []
    waiting = result.get("restart_needed") or []
    if isinstance(changed, list) and changed:
        text += ": " + ", ".join(map(str, changed))
    if isinstance(waiting, list) and waiting:
        text += "; after a restart: " + ", ".join(map(str, waiting))
    return text


def _audit(console: Console, who: Identity, text: str, result: str) -> None:
    console.events.record(
        GatewayEvent(
            "config_changed",
            text,
            who=who.client,
            result=result,
            address=who.address,
            category=Category.CONFIGURATION,
        )
    )
