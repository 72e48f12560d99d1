"""The soak's users besides the checked SCADA clients: an MQTT dashboard sending commands, a
console viewer (pages, events, CSV, history, a login now and then), a Prometheus scraper and an
HMI connecting for every read, each counting what it asked and what went wrong.

A failure is excused only when an outage the scenario caused could explain it (`Outages`): an
MQTT command lost while the broker was away. Everything else is an error the verdict counts.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import json
import logging
import struct
import time
from collections.abc import Collection
from dataclasses import dataclass, field
from typing import Any, Final

import aiohttp
import aiomqtt

ANSWER_TIMEOUT_S: Final = 10.0
"""Longer than any answer of a healthy gateway (a command waits its turn on the line)."""
SETTLE_S: Final = 2.0
"""After an outage ends, what was sent during it may still fail."""
RETRY_S: Final = 0.2
MAX_EXAMPLES: Final = 5
BRIEF_READ_REGISTER: Final = 0x000A  # P00.10: a parameter nobody writes in the soak


@dataclass
class CallStats:
    """What one kind of user asked, and how it went."""

    calls: int = 0
    errors: int = 0
    excused: int = 0
    """Failures an outage explains (the broker away, for MQTT)."""
    examples: list[str] = field(default_factory=list)

    def failed(self, what: str, excuse: str | None) -> None:
        if excuse is not None:
            self.excused += 1
            return
        self.errors += 1
        if len(self.examples) < MAX_EXAMPLES:
            self.examples.append(what[:200])


class Outages:
    """When each outage the scenario caused began and ended (monotonic seconds)."""

    def __init__(self) -> None:
        self._windows: list[tuple[str, float, float | None]] = []

    def begin(self, what: str) -> None:
        self._windows.append((what, time.monotonic(), None))

    def end(self, what: str) -> None:
        for index in range(len(self._windows) - 1, -1, -1):
            name, began, ended = self._windows[index]
            if name == what and ended is None:
                self._windows[index] = (name, began, time.monotonic())
                return

    def excuse(self, kinds: Collection[str], sent_at: float) -> str | None:
        """The outage of one of `kinds` that overlapped a call from `sent_at` to now, if any."""
        now = time.monotonic()
        for name, began, ended in reversed(self._windows):
            overlaps = began <= now and (ended is None or ended + SETTLE_S >= sent_at)
            if name in kinds and overlaps:
                return name
        return None


MQTT_OUTAGES: Final = frozenset({"MQTT broker"})
DRIVE_OUTAGES: Final = frozenset({"stalled drive"})
GATEWAY_TARGET_FAILED: Final = 0x0B
QUIET: Final = logging.getLogger("invt-gateway.soak.mqtt")
"""The dashboard's client logger: a broker killed on purpose is counted, not printed."""
QUIET.addHandler(logging.NullHandler())
QUIET.propagate = False


class MqttCommands:
    """A dashboard on the broker: set-points, parameter reads, fault histories and polls now,
    each awaited on its response topic by its `transaction`; `ask` sends one for the scenario
    (a fault reset)."""

    def __init__(
        self, host: str, port: int, base: str, drives: list[str], outages: Outages
    ) -> None:
        self.host = host
        self.port = port
        self.base = base
        self.drives = drives
        self.outages = outages
        self.stats = CallStats()
        self._client: aiomqtt.Client | None = None
        self._connected = asyncio.Event()
        self._waiting: dict[str, asyncio.Future[dict[str, Any]]] = {}
        self._numbers = itertools.count(1)

    async def run(self, stop: asyncio.Event, pause_s: float) -> None:
        while not stop.is_set():
            client = aiomqtt.Client(
                self.host, self.port, identifier=f"soak-{id(self):x}", logger=QUIET
            )
            try:
                async with client, asyncio.TaskGroup() as tasks:
                    await client.subscribe(f"{self.base}/+/set/response")
                    await client.subscribe(f"{self.base}/bridge/response/#")
                    # Commands go once the gateway says it is online on this broker: before, it
                    # hasn't subscribed yet (at start, after the broker's restart).
                    await client.subscribe(f"{self.base}/bridge/state")
                    self._client = client
                    listening = tasks.create_task(self._listen(client), name="soak:mqtt-listen")
                    await self._command_forever(stop, pause_s)
                    listening.cancel()
            except* aiomqtt.MqttError:
                await asyncio.sleep(RETRY_S)
            finally:
                self._connected.clear()
                self._client = None
                for future in self._waiting.values():
                    if not future.done():  # the scenario's own asks: told at once
                        future.set_exception(aiomqtt.MqttError("the connection was lost"))

    async def ask(self, topic: str, payload: dict[str, Any]) -> dict[str, Any] | None:
        """Publish `payload` (a transaction added) on `<base>/<topic>`; its response, or None
        when it didn't come (counted)."""
        sent_at = time.monotonic()
        self.stats.calls += 1
        transaction = f"soak-{next(self._numbers)}"
        try:
            await asyncio.wait_for(self._connected.wait(), ANSWER_TIMEOUT_S)
            client = self._client
            assert client is not None
            answer = asyncio.get_running_loop().create_future()
            self._waiting[transaction] = answer
            body = json.dumps({**payload, "transaction": transaction})
            await client.publish(f"{self.base}/{topic}", body, qos=1)
            response: dict[str, Any] = await asyncio.wait_for(answer, ANSWER_TIMEOUT_S)
        except (TimeoutError, aiomqtt.MqttError) as exc:
            excuse = self.outages.excuse(MQTT_OUTAGES, sent_at)
            self.stats.failed(f"{topic} {payload}: no response ({exc!r})", excuse)
            return None
        except asyncio.CancelledError:  # the connection went under it (or the run ends)
            excuse = self.outages.excuse(MQTT_OUTAGES, sent_at)
            self.stats.failed(f"{topic} {payload}: connection lost", excuse)
            raise
        finally:
            self._waiting.pop(transaction, None)
        if response.get("status") != "ok":
            # 0BH (offline, no answer) is what a stalled drive's commands get, and only that.
            stalled = response.get("exception_code") == GATEWAY_TARGET_FAILED
            excuse = self.outages.excuse(DRIVE_OUTAGES, sent_at) if stalled else None
            self.stats.failed(f"{topic} {payload}: {response}", excuse)
        return response

    async def _command_forever(self, stop: asyncio.Event, pause_s: float) -> None:
        for number in itertools.count():
            if stop.is_set():
                return
            drive = self.drives[number // 4 % len(self.drives)]
            kind = number % 4
            if kind == 0:
                await self.ask(f"{drive}/set", {"frequency_hz": 10.0 + number % 40})
            elif kind == 1:
                request = {"drive": drive, "parameter": "P07.27", "count": 6}
                await self.ask("bridge/request/read_parameter", request)
            elif kind == 2:
                await self.ask("bridge/request/fault_history", {"drive": drive, "limit": 20})
            else:
                assert self._client is not None
                await self._client.publish(f"{self.base}/{drive}/get", b"")
            await asyncio.sleep(pause_s)

    async def _listen(self, client: aiomqtt.Client) -> None:
        async for message in client.messages:
            with contextlib.suppress(ValueError, TypeError, AttributeError):
                response = json.loads(bytes(message.payload))
                if message.topic.matches(f"{self.base}/bridge/state"):
                    online = response.get("state") == "online"
                    (self._connected.set if online else self._connected.clear)()
                    continue
                future = self._waiting.get(str(response.get("transaction")))
                if future is not None and not future.done():
                    future.set_result(response)


CONSOLE_CALLS: Final = (
    "/api/overview",
    "/api/drives/{drive}",
    "/api/events",
    "/api/events?format=csv",
    "/api/drives/{drive}/history?window=1h",
    "/api/drives/{drive}/faults",
    "/api/diagnostics",
    "/api/drives/{drive}/history?window=24h&points=300",
    "/",
    "/api/log",
)
LOGIN_EVERY: Final = 25
"""Calls between two logins of a browser (a session opened and closed)."""


class ConsoleViewer:
    """A script with the viewer's API token going round the console's pages and APIs, and a
    browser logging in and out now and then."""

    def __init__(self, base: str, token: str, user: str, password: str, drives: list[str]) -> None:
        self.base = base
        self.token = token
        self.user = user
        self.password = password
        self.drives = drives
        self.stats = CallStats()

    async def run(self, stop: asyncio.Event, pause_s: float) -> None:
        headers = {"Authorization": f"Bearer {self.token}"}
        timeout = aiohttp.ClientTimeout(total=ANSWER_TIMEOUT_S)
        async with aiohttp.ClientSession(headers=headers, timeout=timeout) as session:
            for number in itertools.count():
                if stop.is_set():
                    return
                if number % LOGIN_EVERY == LOGIN_EVERY - 1:
                    await self._log_in_and_out()
                else:
                    path = CONSOLE_CALLS[number % len(CONSOLE_CALLS)]
                    drive = self.drives[number % len(self.drives)]
                    await self._get(session, path.format(drive=drive))
                await asyncio.sleep(pause_s)

    async def _get(self, session: aiohttp.ClientSession, path: str) -> None:
        self.stats.calls += 1
        try:
            async with session.get(self.base + path) as response:
                await response.read()
                if response.status != 200:
                    self.stats.failed(f"GET {path}: {response.status}", None)
        except (aiohttp.ClientError, TimeoutError) as exc:
            self.stats.failed(f"GET {path}: {exc!r}", None)

    async def _log_in_and_out(self) -> None:
        """A browser of its own (cookies): a session opened, used once, closed."""
        self.stats.calls += 1
        try:
            # unsafe: aiohttp keeps no cookie of an IP address's (127.0.0.1) otherwise.
            jar = aiohttp.CookieJar(unsafe=True)
            timeout = aiohttp.ClientTimeout(total=ANSWER_TIMEOUT_S)
            async with aiohttp.ClientSession(timeout=timeout, cookie_jar=jar) as browser:
                login = {"name": self.user, "password": self.password}
                async with browser.post(f"{self.base}/api/login", json=login) as response:
                    csrf = (await response.json())["csrf_token"] if response.status == 200 else ""
                    if response.status != 200:
                        self.stats.failed(f"login: {response.status}", None)
                        return
                async with browser.get(f"{self.base}/api/session") as response:
                    if (await response.json()).get("user") != self.user:
                        self.stats.failed(f"session: {response.status}, not {self.user}'s", None)
                logout = {"X-CSRF-Token": csrf}
                async with browser.post(f"{self.base}/api/logout", headers=logout) as response:
                    await response.read()
                    if response.status != 200:
                        self.stats.failed(f"logout: {response.status}", None)
        except (aiohttp.ClientError, TimeoutError, KeyError, ValueError) as exc:
            self.stats.failed(f"login and logout: {exc!r}", None)


class Scraper:
    """Prometheus at a compressed interval: /metrics, and /health now and then (its status
    may say degraded during an outage: only no answer is an error)."""

    def __init__(self, base: str) -> None:
        self.base = base
        self.stats = CallStats()

    async def run(self, stop: asyncio.Event, pause_s: float) -> None:
        timeout = aiohttp.ClientTimeout(total=ANSWER_TIMEOUT_S)
        async with aiohttp.ClientSession(timeout=timeout) as session:
            for number in itertools.count():
                if stop.is_set():
                    return
                path = "/health" if number % 5 == 4 else "/metrics"
                self.stats.calls += 1
                try:
                    async with session.get(self.base + path) as response:
                        await response.read()
                        if response.status not in (200, 503) or (
                            path == "/metrics" and response.status != 200
                        ):
                            self.stats.failed(f"GET {path}: {response.status}", None)
                except (aiohttp.ClientError, TimeoutError) as exc:
                    self.stats.failed(f"GET {path}: {exc!r}", None)
                await asyncio.sleep(pause_s)


class BriefScada:
    """An HMI that connects for every read and closes after it (Node-RED's and many a panel's
    habit): a new client, port and connection for the gateway each time."""

    def __init__(self, port: int, unit_id: int) -> None:
        self.port = port
        self.unit_id = unit_id
        self.stats = CallStats()

    async def run(self, stop: asyncio.Event, pause_s: float) -> None:
        pdu = struct.pack(">BHH", 0x03, BRIEF_READ_REGISTER, 1)
        for number in itertools.count():
            if stop.is_set():
                return
            self.stats.calls += 1
            frame = struct.pack(">HHHB", number & 0xFFFF, 0, len(pdu) + 1, self.unit_id) + pdu
            try:
                answer = await asyncio.wait_for(self._ask(frame), ANSWER_TIMEOUT_S)
                if answer[:2] != frame[:2] or answer[7] != 0x03:
                    self.stats.failed(f"read: answered {answer.hex()}", None)
            except (OSError, asyncio.IncompleteReadError, TimeoutError) as exc:
                self.stats.failed(f"read: {exc!r}", None)
            await asyncio.sleep(pause_s)

    async def _ask(self, frame: bytes) -> bytes:
        reader, writer = await asyncio.open_connection("127.0.0.1", self.port)
        try:
            writer.write(frame)
            header = await reader.readexactly(7)
            return header + await reader.readexactly(struct.unpack(">H", header[4:6])[0] - 1)
        finally:
            writer.close()
            with contextlib.suppress(OSError):
                await writer.wait_closed()
