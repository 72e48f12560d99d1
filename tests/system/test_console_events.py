"""The console's events from the gateway's store: each event once, in words, filtered by kind,
drive and time, and downloaded as CSV, against the gateway on the simulated line."""

from __future__ import annotations

import asyncio
import csv
import io
import struct
import time
from typing import Any

from gateway.app import Application
from gateway.instruments.simulator import SimulatedLine
from gateway.poller.drive_state import iso_time
from tests.support import TcpClient, eventually, running_gateway
from tests.support.console_support import (
    OPERATOR_PASSWORD,
    ConsoleClient,
    console_client,
    console_config,
)

SET_POINT = 0x2001
CONTROL_WORD = 0x2000


async def scada_writes(app: Application) -> None:
    """A SCADA client writes pump1 three times: a set-point twice, then a run command."""
    client = await TcpClient.connect(app.tcp.port)
    try:
        await client.request(1, struct.pack(">BHH", 0x06, SET_POINT, 1000))
        await client.request(1, struct.pack(">BHH", 0x06, SET_POINT, 2000))
        await client.request(1, struct.pack(">BHHBHH", 0x10, CONTROL_WORD, 2, 4, 5, 2000))
    finally:
        await client.close()


async def events(web: ConsoleClient, query: str = "") -> list[dict[str, Any]]:
    found: list[dict[str, Any]] = (await web.get_json(f"/api/events?limit=500&{query}"))["events"]
    return found


async def test_modbus_tcp_writes_show_one_row_each_then_one_row_for_their_minute(
    line: SimulatedLine,
) -> None:
    async with running_gateway(console_config(line.path)) as app, console_client(app) as web:
        assert (await web.login("olga", OPERATOR_PASSWORD)).status == 200
        await scada_writes(app)
        # Within the minute: each write as it happened, not yet in the store.
        pending = await events(web, "kind=modbus_writes")
        assert len(pending) == 3
        assert all(e["pending"] and e["id"] is None for e in pending)
        assert pending[0]["text"] == "function 10H to address 1"
        # The minute is over (a stop does the same): its tally is stored, and only it shows.
        app.writes.flush(until_minute=None)
        await app.events.flush()
        (minute,) = await events(web, "kind=modbus_writes")
        assert minute["id"] is not None
        assert minute["pending"] is False
        assert minute["type"] == "modbus_writes"
        assert minute["kind"] == "write"
        assert minute["text"] == "3 writes to unit 1 (function 06H, 10H; 2001H, 2000H)"
        assert (minute["drive"], minute["who"], minute["result"]) == ("pump1", "127.0.0.1", "ok")
        everything = await events(web)
        ids = [e["id"] for e in everything if e["id"] is not None]
        assert len(ids) == len(set(ids))
        assert not [e for e in everything if e["pending"]]
        assert not [e for e in everything if "{" in e["text"]]  # words, never JSON


async def test_events_are_filtered_by_kind_drive_and_time(line: SimulatedLine) -> None:
    async with running_gateway(console_config(line.path)) as app, console_client(app) as web:
        assert (await web.login("olga", OPERATOR_PASSWORD)).status == 200
        status, _ = await web.post("/api/drives/pump1/command", {"command": "stop"})
        assert status == 200
        # Times go to the API to the millisecond: the two commands at least that far apart.
        await asyncio.sleep(0.01)
        between = time.time()
        await asyncio.sleep(0.01)
        status, _ = await web.post("/api/drives/fan2/command", {"command": "stop"})
        assert status == 200
        line.set_dead(2)

        async def fan2_offline() -> bool:
            return any(e["kind"] == "drive_offline" for e in await events(web, "drive=fan2"))

        await eventually(fan2_offline)
        await app.events.flush()

        commands = await events(web, "kind=command")
        assert [e["drive"] for e in commands] == ["fan2", "pump1"]
        for command in commands:
            assert command["category"] == "control"
            assert command["user"] == "olga"
            assert command["address"] == "127.0.0.1"
            assert command["result"] == "ok"
        logins = await events(web, "kind=login,logout")
        assert [(e["kind"], e["user"], e["result"]) for e in logins] == [("login", "olga", "ok")]
        assert logins[0]["text"] == "olga logged in from 127.0.0.1"
        assert {e["drive"] for e in await events(web, "drive=fan2")} == {"fan2"}
        since = iso_time(between)
        later = await events(web, f"kind=write&since={since}")
        assert [e["drive"] for e in later] == ["fan2"]
        earlier = await events(web, f"kind=write&until={since}")
        assert [e["drive"] for e in earlier] == ["pump1"]
        async with web.session.get(f"{web.base}/api/events?since=2026-11-25T06:00") as response:
            assert response.status == 400
            assert "since: an ISO 8601 time with its zone" in (await response.json())["error"]
        async with web.session.get(f"{web.base}/api/events?drive=pump9") as response:
            assert response.status == 404


async def test_events_download_as_csv_as_filtered(line: SimulatedLine) -> None:
    async with running_gateway(console_config(line.path)) as app, console_client(app) as web:
        assert (await web.login("olga", OPERATOR_PASSWORD)).status == 200
        await scada_writes(app)
        status, _ = await web.post("/api/drives/pump1/command", {"command": "stop"})
        assert status == 200
        await app.events.flush()
        shown = await events(web, "kind=write&drive=pump1")
        async with web.session.get(
            f"{web.base}/api/events?kind=write&drive=pump1&format=csv"
        ) as response:
            assert response.status == 200
            assert response.content_type == "text/csv"
            assert "attachment" in response.headers["Content-Disposition"]
            rows = list(csv.DictReader(io.StringIO(await response.text())))
    assert [row["text"] for row in rows] == [e["text"] for e in shown]
    assert len(rows) == 4
    assert rows[0]["who"] == "console:olga"
    assert rows[0]["user"] == "olga"
    assert rows[0]["category"] == "control"
    assert rows[0]["time"].endswith("Z")
    assert {row["drive"] for row in rows} == {"pump1"}


async def test_a_name_typed_at_the_login_is_exported_as_text_not_a_formula(
    line: SimulatedLine,
) -> None:
    planted = '=HYPERLINK("http://x","y")'
    async with running_gateway(console_config(line.path)) as app, console_client(app) as web:
        # Nobody logged in: a failed login is all it takes to put a name into the events.
        assert (await web.login(planted, "wrong")).status == 401
        assert (await web.login("olga", OPERATOR_PASSWORD)).status == 200
        await app.events.flush()
        async with web.session.get(f"{web.base}/api/events?format=csv") as response:
            assert response.status == 200
            rows = list(csv.DictReader(io.StringIO(await response.text())))
    failed = [row for row in rows if row["kind"] == "login_failed"]
    assert failed, rows
    assert failed[0]["user"] == "'" + planted  # a spreadsheet shows it as text
    cells = [value for row in rows for value in row.values()]
    assert not [c for c in cells if c[:1] in ("=", "+", "-", "@", "\t", "\r")], cells
    assert all(int(row["id"]) > 0 for row in rows)  # numbers are left as numbers
