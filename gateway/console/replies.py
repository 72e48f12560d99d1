"""What a console handler answers with when it can't answer: an HTTP error as JSON naming the
reason, and the query values every API reads (a time, a count) checked the same way."""

from __future__ import annotations

import json
from datetime import datetime
from typing import Any, Final

from aiohttp import web

MAX_EVENTS: Final = 2000
"""The most events one page of the events API carries (`limit`)."""


def http_error(status: int, message: str) -> web.HTTPException:
    body = json.dumps({"ok": False, "error": message})
    return status_class(status)(text=body, content_type="application/json")


def status_class(status: int) -> type[web.HTTPException]:
    return {
        400: web.HTTPBadRequest,
        401: web.HTTPUnauthorized,
        403: web.HTTPForbidden,
        404: web.HTTPNotFound,
        409: web.HTTPConflict,
        429: web.HTTPTooManyRequests,
        502: web.HTTPBadGateway,
        503: web.HTTPServiceUnavailable,
    }[status]


async def json_body(request: web.Request, limit: int) -> dict[str, Any]:
    """The request's body as a JSON object of at most `limit` bytes: 413 past it (before
    reading, when Content-Length says so), 400 for anything that is not such an object."""
    if request.content_type != "application/json":
        raise http_error(400, "send JSON (Content-Type: application/json)")
    size = request.content_length or 0
    raw = bytearray()
    while size <= limit and (chunk := await request.content.readany()):
        raw += chunk
        size = len(raw)
    if size > limit:
        message = json.dumps({"ok": False, "error": f"the body is over {limit // 1024} kB"})
        raise web.HTTPRequestEntityTooLarge(
            limit, size, text=message, content_type="application/json"
        )
    try:
        body = json.loads(raw)
    except RecursionError:  # thousands of nested [ or {: a stack's depth, not a value
        raise http_error(400, "the body is nested too deeply") from None
    except ValueError:
        raise http_error(400, "the body is not valid JSON") from None
    if not isinstance(body, dict):
        raise http_error(400, "the body must be a JSON object")
    return body


def time_query(request: web.Request, key: str) -> float | None:
    value = request.query.get(key)
    if not value:
        return None
    try:
        moment = datetime.fromisoformat(value)
    except ValueError:
        moment = None
    if moment is None or moment.tzinfo is None:
        raise http_error(400, f"{key}: an ISO 8601 time with its zone, e.g. 2026-11-25T06:00:00Z")
    return moment.timestamp()


def query_limit(
    request: web.Request, key: str = "limit", default: int = 200, maximum: int = MAX_EVENTS
) -> int:
    try:
        return max(0, min(int(request.query.get(key, default)), maximum))
    except ValueError:
        raise http_error(400, f"{key}: a whole number") from None
