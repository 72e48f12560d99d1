"""Who logged in, who failed, who logged out, who commanded and wrote what: events in the store
(across a restart), on the console's events and on `<base>/bridge/event`, with what IEC 62443-4-2
CR 2.8 asks of an audit record. And a guesser slows only himself: the operator still logs in.

Real sockets: aiohttp's client from two loopback addresses (127.0.0.1 the operator's desk,
127.0.0.2 the guesser), the gateway on the simulated line, a real Mosquitto.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import aiohttp
import pytest

from gateway.app import Application
from gateway.console.auth import MAX_ADDRESS_FAILURES, MAX_FAILURES
from gateway.instruments.simulator import SimulatedLine
from tests.support import present, running_gateway
from tests.support.console_support import (
    OPERATOR_PASSWORD,
    VIEWER_PASSWORD,
    ConsoleClient,
    console_client,
    console_config,
)
from tests.support.mosquitto import Mosquitto, mqtt_probe, unique_base_topic
from tests.support.mqtt_setup import mqtt_config
from tests.support.service_log import lines, service_log

WRONG = "hunter2-not-olgas"
AUDIT_FIELDS = {"category", "user", "address", "result"}


@contextlib.asynccontextmanager
async def client_from(app: Application, address: str) -> AsyncIterator[ConsoleClient]:
    """A browser on another machine: its connections come from `address`."""
    connector = aiohttp.TCPConnector(local_addr=(address, 0))
    jar = aiohttp.CookieJar(unsafe=True)
    async with aiohttp.ClientSession(connector=connector, cookie_jar=jar) as session:
        yield ConsoleClient(session, f"http://127.0.0.1:{present(app.console).port}")


async def test_a_guesser_elsewhere_slows_only_himself(line: SimulatedLine) -> None:
    async with running_gateway(console_config(line.path)) as app:
        async with client_from(app, "127.0.0.2") as guesser, console_client(app) as olga:
            for _ in range(MAX_FAILURES):
                assert (await guesser.login("olga", WRONG)).status == 401
            throttled = await guesser.login("olga", WRONG)
            assert throttled.status == 429
            first_wait = int(throttled.headers["Retry-After"])
            # The operator, at her own desk, logs in with her password meanwhile.
            assert (await olga.login("olga", OPERATOR_PASSWORD)).status == 200
            # The guesser's waits grow: each failure past the free ones doubles the next.
            await asyncio.sleep(first_wait)
            assert (await guesser.login("olga", WRONG)).status == 401
            second = await guesser.login("olga", WRONG)
            assert second.status == 429
            assert int(second.headers["Retry-After"]) == 2 * first_wait
        started = present(app.console).console
        counts = started.logins if started else None
        assert counts is not None
        assert (counts.ok, counts.failed, counts.throttled) == (1, MAX_FAILURES + 1, 2)


async def test_a_stranger_at_a_shared_pc_does_not_lock_its_other_users_out(
    line: SimulatedLine, caplog: pytest.LogCaptureFixture
) -> None:
    log = service_log(caplog)
    async with (
        running_gateway(console_config(line.path)) as app,
        client_from(app, "127.0.0.2") as stranger,
        client_from(app, "127.0.0.2") as olga,
    ):
        for n in range(MAX_ADDRESS_FAILURES + 1):
            assert (await stranger.login(f"guess{n}", WRONG)).status == 401
        assert (await stranger.login("guess3", WRONG)).status == 429  # his names wait
        # Olga, at the same PC (or behind the same proxy), has not failed: she logs in.
        assert (await olga.login("olga", OPERATOR_PASSWORD)).status == 200
    failed = [line for line in lines(log, "gateway.console") if "failed login" in line]
    assert len(failed) == 1, failed  # 51 failures: each an audit event, one log line a minute


async def audit_events(app: Application) -> list[dict[str, Any]]:
    await app.events.flush()
    stored = await app.events.recent_events(50)
    return [e.payload() for e in reversed(stored) if "category" in e.data]


async def test_logins_logouts_commands_and_writes_are_audit_events_kept_across_a_restart(
    line: SimulatedLine, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.DEBUG)
    async with running_gateway(console_config(line.path)) as app, console_client(app) as olga:
        assert (await olga.login("olga", WRONG)).status == 401
        assert (await olga.login("olga", OPERATOR_PASSWORD)).status == 200
        status, _ = await olga.post("/api/drives/pump1/command", {"command": "stop"})
        assert status == 200
        status, _ = await olga.post("/api/drives/pump1/parameter", {"name": "P00.11", "value": 9})
        assert status == 200
        status, _ = await olga.post("/api/logout", {})
        assert status == 200
        events = await audit_events(app)
        store_file = app.events.path
    kinds = [(e["type"], e["data"]["category"], e["data"]["result"]) for e in events]
    assert kinds == [
        ("login_failed", "authentication", "wrong name or password"),
        ("login", "authentication", "ok"),
        ("command", "control", "ok"),
        ("command", "configuration", "ok"),
        ("logout", "authentication", "ok"),
    ]
    for event in events:  # CR 2.8: time, source (address, user), category, type, id, result
        assert set(event["data"]) >= AUDIT_FIELDS
        assert event["data"]["user"] == "olga"
        assert event["data"]["address"] == "127.0.0.1"
        assert event["id"] > 0
        assert event["time"]
    assert [e["id"] for e in events] == sorted(e["id"] for e in events)
    # The passwords are nowhere: not in the store's file, not in the log.
    stored = await asyncio.to_thread(Path(store_file).read_bytes)  # checkpointed at the stop
    for secret in (WRONG, OPERATOR_PASSWORD):
        assert secret.encode() not in stored
        assert secret not in caplog.text
    # After a restart the console's events still show them, each with its id.
    async with running_gateway(console_config(line.path)) as app, console_client(app) as olga:
        assert (await olga.login("olga", OPERATOR_PASSWORD)).status == 200
        await app.events.flush()
        shown = (await olga.get_json("/api/events?limit=20"))["events"]
    before_restart = {e["id"] for e in events}
    kept = [e for e in shown if e["id"] in before_restart]
    assert {e["category"] for e in kept} == {"authentication", "control", "configuration"}
    failed = next(e for e in kept if e["kind"] == "login_failed")
    assert (failed["who"], failed["address"]) == ("olga", "127.0.0.1")
    assert failed["text"] == "failed login for 'olga' from 127.0.0.1"


async def test_a_write_refused_at_the_door_is_an_audit_event(line: SimulatedLine) -> None:
    async with running_gateway(console_config(line.path)) as app, console_client(app) as victor:
        assert (await victor.login("victor", VIEWER_PASSWORD)).status == 200
        status, _ = await victor.post("/api/drives/pump1/command", {"command": "run_forward"})
        assert status == 403
        events = await audit_events(app)
    refused = events[-1]
    assert refused["type"] == "command"
    data = refused["data"]
    assert (data["drive"], data["user"], data["address"]) == ("pump1", "victor", "127.0.0.1")
    assert data["category"] == "control"
    assert data["result"].startswith("refused: victor (viewer) may not make changes")


async def test_logins_are_published_on_bridge_event(
    line: SimulatedLine, mosquitto: Mosquitto
) -> None:
    base = unique_base_topic()
    console = console_config(line.path).console
    config = mqtt_config(line.path, mosquitto, base).model_copy(update={"console": console})
    topic = f"{base}/bridge/event"
    async with (
        mqtt_probe(mosquitto, topic) as probe,
        running_gateway(config) as app,
        console_client(app) as olga,
    ):
        assert (await olga.login("olga", WRONG)).status == 401
        assert (await olga.login("olga", OPERATOR_PASSWORD)).status == 200
        failed = await probe.wait_for(topic, lambda e: e["type"] == "login_failed")
        login = await probe.wait_for(topic, lambda e: e["type"] == "login")
    for received in (failed, login):
        event = received.json()
        assert {"id", "type", "time", "data"} <= set(event)
        assert event["data"]["user"] == "olga"
        assert event["data"]["address"] == "127.0.0.1"
        assert event["data"]["category"] == "authentication"
        assert WRONG not in received.payload.decode()
    assert failed.json()["data"]["result"] == "wrong name or password"
