"""`invt-gateway monitor [--url URL] [--bus NAME]`: the console's traffic monitor in a terminal.

Reads the running gateway's traffic stream (`/api/buses/NAME/traffic`, server-sent events) and
prints one line per transaction as it happens, until Ctrl-C. The gateway records traffic only
while a monitor (this, or the page) is open. Without `anonymous_view` it needs an API token:
`--token`, or better the environment variable INVT_GATEWAY_CONSOLE_TOKEN (not in `ps`).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import sys
from collections.abc import AsyncIterator
from datetime import datetime
from typing import Any

from gateway.errors import MonitorError
from gateway.exit_codes import EXIT_FAILURE, EXIT_OK, EXIT_USAGE

DEFAULT_URL = "http://127.0.0.1:8080/"
ENV_TOKEN = "INVT_GATEWAY_CONSOLE_TOKEN"


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "monitor",
        help="print every transaction on a bus as it happens (the console's traffic monitor)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--url", default=DEFAULT_URL, help=f"the console (default {DEFAULT_URL})")
    parser.add_argument("--bus", help="the bus to watch (default: the first)")
    parser.add_argument("--token", help=f"API token (better: ${ENV_TOKEN})")
    parser.add_argument("--hex", action="store_true", help="print each frame in hex too")
    parser.add_argument(
        "--recent", type=int, default=20, metavar="N", help="first the last N recorded (20)"
    )
    parser.set_defaults(handler=handle)


def handle(args: argparse.Namespace) -> int:
    if not args.url.startswith(("http://", "https://")):
        print(
            f"invt-gateway monitor: --url {args.url}: must start with http:// or https://",
            file=sys.stderr,
        )
        return EXIT_USAGE
    token = args.token or os.environ.get(ENV_TOKEN)
    try:
        asyncio.run(monitor(args.url.rstrip("/"), args.bus, token, args.hex, args.recent))
    except MonitorError as exc:
        print(f"invt-gateway monitor: {exc}", file=sys.stderr)
        return EXIT_FAILURE
    return EXIT_OK


async def monitor(base: str, bus: str | None, token: str | None, hex_: bool, recent: int) -> None:
    import aiohttp  # only the monitor and the console need it

    headers = {"Authorization": f"Bearer {token}"} if token else {}
    timeout = aiohttp.ClientTimeout(total=None, connect=5, sock_read=None)
    try:
        async with aiohttp.ClientSession(headers=headers, timeout=timeout) as session:
            if bus is None:
                bus = await _first_bus(session, base)
            url = f"{base}/api/buses/{bus}/traffic?recent={max(recent, 0)}"
            async with session.get(url) as response:
                await _check(response, url)
                async for event, data in _events(response):
                    if event == "watching":
                        print(
                            f"watching {data['bus']} at {base} (Ctrl-C to stop)",
                            file=sys.stderr,
                            flush=True,
                        )
                    elif event == "traffic":
                        print(format_line(data, hex_), flush=True)
    except aiohttp.ClientError as exc:
        raise MonitorError(f"{base}: {exc}") from None
    raise MonitorError(f"{base}: the gateway ended the stream (stopped?)")


async def _first_bus(session: Any, base: str) -> str:
    url = f"{base}/api/overview"
    async with session.get(url) as response:
        await _check(response, url)
        buses = (await response.json())["buses"]
    if not buses:
        raise MonitorError(f"{base}: the gateway has no bus")
    return str(buses[0]["name"])


async def _check(response: Any, url: str) -> None:
    if response.status == 200:
        return
    try:
        reason = (await response.json())["error"]
    except (ValueError, KeyError, TypeError):
        reason = response.reason
    raise MonitorError(f"{url}: {response.status} {reason}")


async def _events(response: Any) -> AsyncIterator[tuple[str, Any]]:
    event = ""
    async for raw in response.content:
        line = raw.decode("utf-8", errors="replace").rstrip("\r\n")
        if line.startswith("event: "):
            event = line.removeprefix("event: ")
        elif line.startswith("data: "):
            yield event, json.loads(line.removeprefix("data: "))


def _split(record: dict[str, Any]) -> str:
    """ ": queue 0.1, wire 1.4, drive 5.2" (a gateway before the split: nothing)."""
    parts = [
        f"{label} {record[key]}"
        for label, key in (("queue", "queue_ms"), ("wire", "wire_ms"), ("drive", "turnaround_ms"))
        if record.get(key) is not None
    ]
    return f": {', '.join(parts)}" if parts else ""


def format_line(record: dict[str, Any], hex_: bool) -> str:
    """ "23:09:43.664  tcp:127.0.0.1:40112  unit   1 pump1  03H  read 2100H … → …  ok  7.1 ms"."""
    at = datetime.fromisoformat(str(record["time"]).replace("Z", "+00:00")).astimezone()
    clock = at.strftime("%H:%M:%S.") + f"{at.microsecond // 1000:03d}"  # local time, as the page
    unit = "-" if record.get("unit_id") is None else str(record["unit_id"])
    drive = record.get("drive") or f"address {record['address']}"
    line = (
        f"{clock}  {record['client']:<22} unit {unit:>3} {drive:<10} {record['function']:<4} "
        f"{record['meaning']}  [{record['outcome']}, {record['latency_ms']} ms{_split(record)}]"
    )
    if hex_:
        line += f"\n    -> {record['request_hex']}\n    <- {record['reply_hex'] or '(nothing)'}"
    return line
