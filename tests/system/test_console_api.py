"""The console's JSON API against the gateway on the simulated line: who may see and do what,
writes under Modbus-TCP's policy, the live state, and the traffic monitor's stream."""

from __future__ import annotations

import asyncio
import json
import ssl
import struct
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any
from urllib.parse import quote

import aiohttp
import pytest

from gateway.app import Application
from gateway.console.auth import MAX_FAILURES
from gateway.instruments.simulator import SimulatedLine
from gateway.profile import get_profile
from tests.support import TcpClient, eventually, present, read_pdu, running_gateway
from tests.support.console_support import (
    OPERATOR_PASSWORD,
    OPERATOR_TOKEN,
    VIEWER_PASSWORD,
    ConsoleClient,
    console_client,
    console_config,
    state_word,
)
from tests.support.tls import make_certificates

STATE_WORD_1 = 0x2100
RUNNING_FORWARD = 1
STOPPED = 3


async def test_nobody_sees_anything_without_a_login(line: SimulatedLine) -> None:
    async with running_gateway(console_config(line.path)) as app, console_client(app) as web:
        async with web.session.get(f"{web.base}/api/overview") as response:
            assert response.status == 401
        async with web.session.get(f"{web.base}/", allow_redirects=False) as response:
            assert response.status == 302
            assert response.headers["Location"].startswith("/login")


async def test_the_icon_is_served_to_anyone_and_every_page_links_it(line: SimulatedLine) -> None:
    """Every browser asks for /favicon.ico: an icon, not a 404 (nor the login page) each time."""
    async with running_gateway(console_config(line.path)) as app, console_client(app) as web:
        async with web.session.get(f"{web.base}/favicon.ico", allow_redirects=False) as response:
            assert response.status == 200
            assert response.content_type == "image/x-icon"
            icon = await response.read()
        assert icon[:4] == b"\x00\x00\x01\x00"  # an ICO file's header: reserved 0, type 1
        assert icon[22:30] == b"\x89PNG\r\n\x1a\n"  # its one image, a PNG
        async with web.session.get(f"{web.base}/login") as response:
            assert '<link rel="icon" href="/favicon.ico">' in await response.text()


async def test_overview_lists_the_drives_with_their_polled_state(line: SimulatedLine) -> None:
    async with running_gateway(console_config(line.path)) as app, console_client(app) as web:
        assert (await web.login("victor", VIEWER_PASSWORD)).status == 200

        async def polled() -> bool:
            drives = (await web.get_json("/api/overview"))["drives"]
            return all(d["online"] for d in drives)

        await eventually(polled)
        overview = await web.get_json("/api/overview")
        assert [d["name"] for d in overview["drives"]] == ["pump1", "fan2"]
        pump = overview["drives"][0]
        assert (pump["unit_id"], pump["address"], pump["model"]) == (1, 1, "gd350")
        assert pump["state"] == "stopped"
        assert pump["fault_name"] == "none"
        assert pump["output_frequency_hz"] == 0.0
        bus = overview["buses"][0]
        assert (bus["name"], bus["state"], bus["format"]) == ("line1", "open", "115200 8E1")
        assert bus["port"] == line.path


async def test_a_wrong_password_is_refused_then_rate_limited(line: SimulatedLine) -> None:
    async with running_gateway(console_config(line.path)) as app, console_client(app) as web:
        for _ in range(MAX_FAILURES):
            response = await web.login("olga", "not-her-password")
            assert response.status == 401
            assert (await response.json())["error"] == "wrong name or password"
        # The right password now waits too: a guesser can't tell it found it.
        response = await web.login("olga", OPERATOR_PASSWORD)
        assert response.status == 429
        assert int(response.headers["Retry-After"]) > 0
        assert "too many failed logins" in (await response.json())["error"]


async def test_the_session_cookie_is_httponly_and_samesite_strict(line: SimulatedLine) -> None:
    async with running_gateway(console_config(line.path)) as app, console_client(app) as web:
        response = await web.login("olga", OPERATOR_PASSWORD)
        cookie = response.headers["Set-Cookie"]
        assert "HttpOnly" in cookie
        assert "SameSite=Strict" in cookie


async def test_an_operator_starts_a_drive_and_it_runs(line: SimulatedLine) -> None:
    async with running_gateway(console_config(line.path)) as app, console_client(app) as web:
        await web.login("olga", OPERATOR_PASSWORD)
        status, body = await web.post("/api/drives/pump1/frequency", {"hz": 20.0})
        assert (status, body["ok"]) == (200, True)
        status, body = await web.post("/api/drives/pump1/command", {"command": "run_forward"})
        assert status == 200, body
        assert body["write"] == "2000H control word = 1 (run_forward)"

        async def running() -> bool:
            return await state_word(app, 1) == RUNNING_FORWARD

        await eventually(running)
        events = (await web.get_json("/api/events?drive=pump1"))["events"]
        audit = [e for e in events if e["kind"] == "write"]
        assert audit[0]["who"] == "console:olga"
        assert audit[0]["result"] == "ok"
        assert audit[0]["text"] == "2000H control word = 1 (run_forward)"


async def test_a_write_without_the_csrf_token_is_refused(line: SimulatedLine) -> None:
    async with running_gateway(console_config(line.path)) as app, console_client(app) as web:
        await web.login("olga", OPERATOR_PASSWORD)
        status, body = await web.post(
            "/api/drives/pump1/command", {"command": "run_forward"}, csrf=False
        )
        assert status == 403
        assert "CSRF" in body["error"]
        status, _ = await web.post(
            "/api/drives/pump1/command", {"command": "run_forward"}, Origin="http://evil.example"
        )
        assert status == 403
        assert await state_word(app, 1) == STOPPED


async def test_a_viewers_write_is_refused_and_the_drive_unchanged(line: SimulatedLine) -> None:
    async with running_gateway(console_config(line.path)) as app, console_client(app) as web:
        await web.login("victor", VIEWER_PASSWORD)
        status, body = await web.post("/api/drives/pump1/command", {"command": "run_forward"})
        assert status == 403
        assert "operators only" in body["error"]
        assert await state_word(app, 1) == STOPPED


async def test_anonymous_viewers_see_but_never_write(line: SimulatedLine) -> None:
    config = console_config(line.path, anonymous_view=True)
    async with running_gateway(config) as app, console_client(app) as web:
        assert (await web.get_json("/api/session"))["role"] == "viewer"
        assert len((await web.get_json("/api/overview"))["drives"]) == 2
        status, _ = await web.post("/api/drives/pump1/command", {"command": "run_forward"})
        assert status == 403


async def test_a_script_uses_its_api_token_without_cookie_or_csrf(line: SimulatedLine) -> None:
    async with running_gateway(console_config(line.path)) as app, console_client(app) as web:
        bearer = f"Bearer {OPERATOR_TOKEN}"
        status, body = await web.post(
            "/api/drives/fan2/command", {"command": "run_forward"}, Authorization=bearer
        )
        assert status == 200, body

        async def running() -> bool:
            return await state_word(app, 2) == RUNNING_FORWARD

        await eventually(running)
        wrong = "Bearer not-a-token"
        status, _ = await web.post(
            "/api/drives/fan2/command", {"command": "stop"}, Authorization=wrong
        )
        assert status == 401


@pytest.mark.parametrize(
    ("console", "reason"),
    [
        ({"commands_enabled": False}, "console.commands_enabled is false"),
        ({"modbus_tcp": {"read_only": True}}, "modbus_tcp.read_only"),
        (
            {
                "modbus_tcp": {
                    "access": [{"name": "no-control", "registers": ["2000H"], "allow": False}]
                }
            },
            "modbus_tcp.access rule no-control",
        ),
    ],
)
async def test_console_writes_obey_modbus_tcp_policy(
    line: SimulatedLine, console: dict[str, Any], reason: str
) -> None:
    async with (
        running_gateway(console_config(line.path, **console)) as app,
        console_client(app) as web,
    ):
        await web.login("olga", OPERATOR_PASSWORD)
        status, body = await web.post("/api/drives/pump1/command", {"command": "run_forward"})
        assert status == 403
        assert reason in body["error"]
        assert await state_word(app, 1) == STOPPED


async def test_a_parameter_write_to_ram_goes_to_the_ram_address(line: SimulatedLine) -> None:
    async with running_gateway(console_config(line.path)) as app, console_client(app) as web:
        await web.login("olga", OPERATOR_PASSWORD)
        status, body = await web.post(
            "/api/drives/pump1/parameter", {"name": "P00.11", "value": "12.5", "ram": True}
        )
        assert status == 200, body
        assert body["write"] == "P00.11 (RAM) = 12.5 s"
        group = await web.get_json("/api/drives/pump1/parameters?group=P00")
        accel = next(p for p in group["parameters"] if p["name"] == "P00.11")
        assert (accel["raw"], accel["value"], accel["unit"]) == (125, "12.5 s", "s")
        status, body = await web.post(
            "/api/drives/pump1/parameter", {"name": "P07.27", "value": "1", "ram": False}
        )
        assert (status, body["error"]) == (400, "P07.27 is read-only")


async def test_every_group_of_the_series_table_shows_with_the_manuals_words(
    line: SimulatedLine,
) -> None:
    async with running_gateway(console_config(line.path)) as app, console_client(app) as web:
        await web.login("olga", OPERATOR_PASSWORD)
        inputs = (await web.get_json("/api/drives/pump1/parameters?group=P05"))["parameters"]
        assert len(inputs) > 40  # the GD350's table (GD200A's, unconfirmed): was empty
        s1 = next(p for p in inputs if p["name"] == "P05.01")
        assert (s1["raw"], s1["value"], s1["confirmed"]) == (1, "1 (forward rotation)", False)
        assert {"value": 10, "words": "frequency UP"} in s1["choices"]
        status, body = await web.post(
            "/api/drives/pump1/parameter", {"name": "P03.12", "value": "-50.0", "ram": False}
        )
        assert status == 200, body  # scaled and signed as the series table says
        vector = (await web.get_json("/api/drives/pump1/parameters?group=P03"))["parameters"]
        torque = next(p for p in vector if p["name"] == "P03.12")
        assert (torque["raw"], torque["value"]) == (0xFE0C, "-50.0 %")
        # P00.00 and P00.07 as the Goodrive200A manual gives them, unconfirmed for a GD350 (the
        # common table's range 0-3 and default 15 had no source).
        basic = (await web.get_json("/api/drives/pump1/parameters?group=P00"))["parameters"]
        mode = next(p for p in basic if p["name"] == "P00.00")
        command_b = next(p for p in basic if p["name"] == "P00.07")
        assert (mode["range"], mode["confirmed"]) == ("1 ... 2", False)
        assert (command_b["default"].split()[0], command_b["confirmed"]) == ("2", False)
        # A borrowed range is the drive's to check: its refusal comes back saying so.
        status, body = await web.post(
            "/api/drives/pump1/parameter", {"name": "P01.00", "value": "5", "ram": False}
        )
        assert status == 502
        assert body["error"] == (
            "drive refused: 04H operation failure: the written value is invalid; P01.00's range "
            "is another series' (the table is borrowed, unconfirmed for gd350): the drive "
            "checked it"
        )


async def test_the_parameter_browser_gives_range_default_and_finds_by_number_or_name(
    line: SimulatedLine,
) -> None:
    """What a technician asks of the browser: which groups, what a value may be, what the
    factory set and whether it was changed, and where P00.03 (or "acc time") is."""
    async with running_gateway(console_config(line.path)) as app, console_client(app) as web:
        await web.login("olga", OPERATOR_PASSWORD)
        basic = await web.get_json("/api/drives/pump1/parameters?group=P00")
        groups = sorted({row.group for row in get_profile("gd350").parameters})
        assert basic["groups"] == [*groups, "2000H", "2100H", "3000H"]
        assert "P24" in basic["groups"]  # water supply: a group the fixed P00-P17 tabs missed
        rows = {p["name"]: p for p in basic["parameters"]}
        top = rows["P00.03"]
        assert (top["value"], top["default"], top["differs_from_default"]) == (
            "50.00 Hz", "50.00 Hz", False,
        )  # fmt: skip
        assert top["range"] == "0.00 ... 630.00 Hz, at least P00.04"
        assert top["change"] == "any time"
        limit = rows["P00.04"]["range"]
        assert limit == "0.00 ... 630.00 Hz, within P00.05 ... P00.03"
        # "depends on model": no default to differ from, and the page says so.
        accel = rows["P00.11"]
        assert (accel["default"], accel["differs_from_default"]) == (None, None)
        direction = rows["P00.13"]
        assert direction["value"] == "0 (default)"
        assert {"value": 2, "words": "reverse forbidden"} in direction["choices"]

        status, body = await web.post(
            "/api/drives/pump1/parameter", {"name": "P00.03", "value": "60Hz", "ram": False}
        )
        assert status == 200, body
        for spelled in ("P00.03", "p0.3", "0003H", "0x0003"):
            found = await web.get_json(f"/api/drives/pump1/parameters?find={quote(spelled)}")
            assert [p["name"] for p in found["parameters"]] == ["P00.03"], spelled
            top = found["parameters"][0]
            assert (top["value"], top["default"], top["differs_from_default"]) == (
                "60.00 Hz", "50.00 Hz", True,
            )  # fmt: skip
        named = await web.get_json(f"/api/drives/pump1/parameters?find={quote('ACC time')}")
        names = [p["name"] for p in named["parameters"]]
        assert "P00.11" in names  # "acceleration time 1"
        assert all(
            "acc" in p["description"].lower() and "time" in p["description"].lower()
            for p in named["parameters"]
        )
        nothing = await web.get_json(f"/api/drives/pump1/parameters?find={quote('P99.99')}")
        assert nothing["parameters"] == []
        async with web.session.get(f"{web.base}/api/drives/pump1/parameters?group=P16") as got:
            assert got.status == 404
            assert "no group 'P16': one of P00, P01" in (await got.json())["error"]


async def test_fault_history_is_decoded_with_the_drives_table(line: SimulatedLine) -> None:
    line.set_fault_history(1, [35, 0, 0, 0, 0, 0])
    async with running_gateway(console_config(line.path)) as app, console_client(app) as web:
        await web.login("victor", VIEWER_PASSWORD)
        faults = await web.get_json("/api/drives/pump1/faults")
        first = faults["fault_history"][0]
        assert (first["parameter"], first["code"], first["name"]) == ("P07.27", 35, "STo")
        assert faults["fault_history"][1]["name"] == "none"


@pytest.fixture
async def traffic(line: SimulatedLine) -> AsyncIterator[tuple[Application, ConsoleClient]]:
    async with running_gateway(console_config(line.path)) as app, console_client(app) as web:
        await web.login("victor", VIEWER_PASSWORD)
        yield app, web


async def read_events(response: aiohttp.ClientResponse) -> AsyncIterator[tuple[str, Any]]:
    event = ""
    async for raw in response.content:
        line = raw.decode().rstrip("\n")
        if line.startswith("event: "):
            event = line.removeprefix("event: ")
        elif line.startswith("data: "):
            yield event, json.loads(line.removeprefix("data: "))


async def test_the_monitor_records_at_all_times_and_streams_a_read_as_it_happens(
    traffic: tuple[Application, ConsoleClient],
) -> None:
    app, web = traffic
    bus = app.buses["line1"]
    started = present(app.console).console
    assert started is not None  # the console has started
    monitor = started.traffic
    client = await TcpClient.connect(app.tcp.port)
    await client.request(1, read_pdu(STATE_WORD_1))
    assert bus.tap is not None  # recording before anybody watches
    assert any(r.client.startswith("tcp:") for r in monitor.recent("line1"))
    async with web.session.get(f"{web.base}/api/buses/line1/traffic") as response:
        events = read_events(response)
        assert await anext(events) == ("watching", {"bus": "line1"})
        await client.request(1, read_pdu(STATE_WORD_1))
        async with asyncio.timeout(1.0):
            async for kind, record in events:
                if kind == "traffic" and record["client"].startswith("tcp:"):
                    break
        assert record["meaning"] == "read 2100H state word 1 → 0003H stopped"
        assert (record["unit_id"], record["drive"], record["outcome"]) == (1, "pump1", "ok")
        assert record["request_hex"].startswith("01 03 21 00 00 01")
    await client.close()
    # The watcher gone, the ring goes on: the next problem is kept for whoever looks next.
    recorded = monitor.recorded
    await eventually(lambda: monitor.recorded > recorded, 5.0, "polls recorded after the stream")
    assert bus.tap is not None


async def test_a_dead_drive_goes_offline_and_its_timeouts_show(
    traffic: tuple[Application, ConsoleClient], line: SimulatedLine
) -> None:
    _, web = traffic
    async with web.session.get(f"{web.base}/api/buses/line1/traffic") as response:
        events = read_events(response)
        await anext(events)
        line.set_dead(2)
        async with asyncio.timeout(5.0):
            async for kind, record in events:
                if (
                    kind == "traffic"
                    and record["drive"] == "fan2"
                    and "timeout" in record["outcome"]
                ):
                    break
            assert record["meaning"].startswith("read ")
            # Its retry begins with a marker (it may still answer the request that timed
            # out): shown as what it is, before the request, client "resync".
            async for kind, record in events:
                if kind == "traffic" and record["drive"] == "fan2" and record["client"] == "resync":
                    break
        assert record["request_hex"].startswith("02 0")

    async def offline() -> bool:
        drives = (await web.get_json("/api/overview"))["drives"]
        return next(d for d in drives if d["name"] == "fan2")["online"] is False

    await eventually(offline)
    events_seen = (await web.get_json("/api/events?drive=fan2"))["events"]
    assert any(e["kind"] == "drive_offline" for e in events_seen)


async def test_a_modbus_tcp_write_shows_on_the_overview(
    traffic: tuple[Application, ConsoleClient],
) -> None:
    app, web = traffic
    client = await TcpClient.connect(app.tcp.port)
    await client.request(1, struct.pack(">BHHBHH", 0x10, 0x2000, 2, 4, 1, 3000))
    await client.close()

    async def shows_running() -> bool:
        pump = (await web.get_json("/api/overview"))["drives"][0]
        return bool(pump["state"] == "running forward")

    await eventually(shows_running, within_s=2.0)
    audit = (await web.get_json("/api/events?drive=pump1"))["events"][0]
    assert audit["kind"] == "write"
    assert audit["text"] == "function 10H to address 1"
    assert audit["who"].startswith("tcp:127.0.0.1:")
    assert audit["result"] == "ok"


async def test_open_streams_do_not_hold_up_the_shutdown(line: SimulatedLine) -> None:
    """The service promises to stop within 2 s: a browser's open monitor and live page end."""
    config = console_config(line.path, anonymous_view=True)
    async with aiohttp.ClientSession() as session:
        async with running_gateway(config) as app:
            base = f"http://127.0.0.1:{present(app.console).port}"
            traffic = await session.get(f"{base}/api/buses/line1/traffic")
            live = await session.get(f"{base}/api/live")
            assert (await traffic.content.readline()).startswith(b"event: watching")
            assert (await live.content.readline()).startswith(b"event: overview")
            stopping_from = asyncio.get_running_loop().time()
        assert asyncio.get_running_loop().time() - stopping_from < 2.0
        rest = await traffic.content.read()  # to the end of the stream: the gateway ended it
        assert rest == b"" or rest.endswith(b"\n\n")  # after a whole event, never in one
        traffic.release()
        live.release()


async def test_with_a_certificate_the_console_speaks_https_only(
    line: SimulatedLine, tmp_path: Path
) -> None:
    certificates = make_certificates(tmp_path)
    config = console_config(
        line.path, cert_file=str(certificates.server_cert), key_file=str(certificates.server_key)
    )
    trusting = ssl.create_default_context(cafile=str(certificates.ca))
    async with running_gateway(config) as app, aiohttp.ClientSession() as session:
        port = present(app.console).port
        assert present(app.console).url == f"https://127.0.0.1:{port}/"
        login = {"name": "olga", "password": OPERATOR_PASSWORD}
        async with session.post(
            f"https://127.0.0.1:{port}/api/login", json=login, ssl=trusting
        ) as response:
            assert response.status == 200
            assert "Secure" in response.headers["Set-Cookie"]
        with pytest.raises(aiohttp.ClientError):
            async with session.get(f"http://127.0.0.1:{port}/api/overview") as response:
                await response.read()


async def test_a_lost_port_and_its_return_are_events(
    traffic: tuple[Application, ConsoleClient], line: SimulatedLine
) -> None:
    _, web = traffic

    def kinds(events: list[dict[str, Any]]) -> list[str]:
        return [e["kind"] for e in events if e["bus"] == "line1" and e["drive"] is None]

    async def seen(kind: str) -> bool:
        return kind in kinds((await web.get_json("/api/events"))["events"])

    line.unplug()
    await eventually(lambda: seen("port_lost"))
    line.replug()
    await eventually(lambda: seen("port_back"), within_s=15.0)
    bus = (await web.get_json("/api/overview"))["buses"][0]
    assert bus["state"] == "open"


async def test_faults_and_events_come_from_the_store_across_a_restart(line: SimulatedLine) -> None:
    # The gateway's store (storage.path under this test's STATE_DIRECTORY) outlives a restart:
    # what the console shows of a drive's faults and events comes from it, not from memory.
    async with running_gateway(console_config(line.path)) as app, console_client(app) as web:
        assert (await web.login("victor", VIEWER_PASSWORD)).status == 200

        async def raised() -> bool:
            events = (await web.get_json("/api/events?drive=pump1"))["events"]
            return any(e["kind"] == "fault_raised" for e in events)

        line.inject_fault(1, 11)
        await eventually(raised)
        line.clear_fault(1)

        async def cleared() -> bool:
            faults = (await web.get_json("/api/drives/pump1/faults"))["recorded_faults"]
            return bool(faults) and faults[0]["cleared"] is not None

        await eventually(cleared)
    async with running_gateway(console_config(line.path)) as app, console_client(app) as web:
        assert (await web.login("victor", VIEWER_PASSWORD)).status == 200
        answer = await web.get_json("/api/drives/pump1/faults")
        (fault,) = answer["recorded_faults"]
        assert (fault["code"], fault["name"]) == (11, "OL1")
        assert fault["duration_s"] > 0
        kinds = [e["kind"] for e in answer["events"]]
        assert "fault_raised" in kinds
        assert "fault_cleared" in kinds
