"""A real Mosquitto broker per test, on a free loopback port, that a test can kill and restart.

Never the system's broker on 1883: a test must own its broker to stop it, and must not see what
another program left retained there. Use the `mosquitto` fixture, or `running_mosquitto()` where a
fixture doesn't fit, and `MqttProbe` to watch topics and publish as a dashboard would.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import shutil
import socket
import subprocess
import time
import uuid
from collections.abc import AsyncIterator, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import aiomqtt
import pytest

from tests.support import free_port

MOSQUITTO = shutil.which("mosquitto") or "/usr/sbin/mosquitto"
START_TIMEOUT_S = 5.0


class Mosquitto:
    """One broker process; `stop()`/`start()` keep its port, as a restarted broker would."""

    def __init__(self, directory: Path, port: int | None = None, persistent: bool = False) -> None:
        """`persistent`: sessions and their queued messages survive a `stop(graceful=True)`."""
        self.host = "127.0.0.1"
        self.port = port or free_port()
        self.directory = directory
        self.config_file = directory / f"mosquitto-{self.port}.conf"
        self.log_file = directory / f"mosquitto-{self.port}.log"
        self.persistence_file = directory / f"mosquitto-{self.port}.db" if persistent else None
        persistence = (
            f"persistence true\npersistence_location {directory}/\n"
            f"persistence_file mosquitto-{self.port}.db\n"
            if persistent
            else "persistence false\n"
        )
        # Started as root, Mosquitto would become user "mosquitto", who can't write a test's
        # private temporary directory: no log, and no persistence (a "persistent" broker lost
        # the dashboard's session at every restart, and the store-and-forward test flaked on
        # it). As anyone else it stays who it is.
        user = "user root\n" if os.geteuid() == 0 else ""
        self.config_file.write_text(
            f"{user}listener {self.port} {self.host}\n"
            "allow_anonymous true\n"
            f"{persistence}"
            "log_type error\nlog_type warning\nlog_type notice\n"
            f"log_dest file {self.log_file}\n",
            encoding="utf-8",
        )
        self._process: subprocess.Popen[bytes] | None = None

    @property
    def running(self) -> bool:
        return self._process is not None and self._process.poll() is None

    def start(self) -> None:
        if not Path(MOSQUITTO).exists():
            pytest.fail(f"{MOSQUITTO} not found: install the Debian package mosquitto")
        self._process = subprocess.Popen(
            [MOSQUITTO, "-c", str(self.config_file)],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
        )
        deadline = time.monotonic() + START_TIMEOUT_S
        while time.monotonic() < deadline:
            if self._process.poll() is not None:
                error = self._process.stderr.read().decode() if self._process.stderr else ""
                raise RuntimeError(f"mosquitto exited at start: {error} {self.log()}")
            with (
                contextlib.suppress(OSError),
                socket.create_connection((self.host, self.port), 0.2),
            ):
                return
            time.sleep(0.02)  # polled with a deadline: another process's port
        raise RuntimeError(f"mosquitto did not listen on {self.port}: {self.log()}")

    def stop(self, graceful: bool = False) -> None:
        """Kill the broker at once (SIGKILL): clients see their connection drop. `graceful`:
        SIGTERM, so that a persistent broker saves its sessions first."""
        process, self._process = self._process, None
        if process is not None and process.poll() is None:
            if graceful:
                process.terminate()
            else:
                process.kill()
            process.wait(5)
            if graceful and self.persistence_file is not None:
                # What the persistent tests stand on: else they would race the gateway instead.
                assert self.persistence_file.exists(), f"no sessions saved: {self.log()}"
        if process is not None and process.stderr is not None:
            process.stderr.close()

    def log(self) -> str:
        try:
            return self.log_file.read_text(encoding="utf-8")
        except OSError:
            return ""


@contextlib.contextmanager
def running_mosquitto(directory: Path) -> Iterator[Mosquitto]:
    broker = Mosquitto(directory)
    broker.start()
    try:
        yield broker
    finally:
        broker.stop()


@pytest.fixture
def mosquitto(tmp_path: Path) -> Iterator[Mosquitto]:
    with running_mosquitto(tmp_path) as broker:
        yield broker


def unique_base_topic(prefix: str = "test") -> str:
    """A topic tree no other test (nor anything left retained) uses."""
    return f"{prefix}-{uuid.uuid4().hex[:10]}"


class BrokerAddress(Protocol):
    """Where a broker listens: a `Mosquitto`, or `Address` for any other broker."""

    @property
    def host(self) -> str: ...

    @property
    def port(self) -> int: ...


@dataclass(frozen=True)
class Address:
    host: str
    port: int


class Match(Protocol):
    """A test of a message's JSON payload (its text if it isn't JSON). A Protocol, not a
    `Callable[[Any], bool]`: mypy infers no type for a lambda with more parameters than such a
    Callable, and tests in a loop bind the loop's variable as a default (`lambda m, n=n: ...`)."""

    def __call__(self, value: Any, /) -> bool: ...


@dataclass(frozen=True)
class Received:
    topic: str
    payload: bytes
    retain: bool
    at: float
    qos: int = 1
    """The QoS it came with: the lower of the publisher's and the subscription's."""

    def json(self) -> Any:
        return json.loads(self.payload)


class MqttProbe:
    """A dashboard's view: everything on the subscribed topics, kept in order, and a publisher."""

    def __init__(self, client: aiomqtt.Client) -> None:
        self.client = client
        self.messages: list[Received] = []
        self._changed = asyncio.Condition()

    async def _collect(self) -> None:
        async for message in self.client.messages:
            payload = message.payload
            data = payload if isinstance(payload, bytes) else str(payload or "").encode()
            received = Received(
                str(message.topic), data, bool(message.retain), time.monotonic(), message.qos
            )
            async with self._changed:
                self.messages.append(received)
                self._changed.notify_all()

    async def wait_for(
        self,
        topic: str,
        match: Match = lambda _: True,
        timeout_s: float = 10.0,
        after: int = 0,
    ) -> Received:
        """The first message on `topic` (from index `after`) whose JSON payload matches."""

        def found() -> Received | None:
            for received in self.messages[after:]:
                if received.topic == topic and _matches(received, match):
                    return received
            return None

        async with self._changed:
            try:
                await asyncio.wait_for(
                    self._changed.wait_for(lambda: found() is not None), timeout_s
                )
            except TimeoutError:
                seen = [(m.topic, m.payload[:200]) for m in self.messages[after:]][-20:]
                raise AssertionError(
                    f"nothing matching on {topic} within {timeout_s} s; saw {seen}"
                ) from None
        result = found()
        assert result is not None
        return result

    def on(self, topic: str) -> list[Received]:
        return [m for m in self.messages if m.topic == topic]

    async def publish(self, topic: str, payload: Any, retain: bool = False) -> None:
        data = payload if isinstance(payload, str | bytes) else json.dumps(payload)
        await self.client.publish(topic, data, qos=1, retain=retain)

    async def request(
        self, topic: str, payload: dict[str, Any], response_topic: str, timeout_s: float = 10.0
    ) -> Any:
        """Publish a command with a fresh transaction; its response's JSON."""
        transaction = uuid.uuid4().hex[:8]
        mark = len(self.messages)
        await self.publish(topic, {**payload, "transaction": transaction})
        response = await self.wait_for(
            response_topic, lambda r: r.get("transaction") == transaction, timeout_s, mark
        )
        return response.json()


def _matches(received: Received, match: Match) -> bool:
    try:
        value = received.json()
    except ValueError:
        value = received.payload.decode(errors="replace")
    try:
        return bool(match(value))
    except (KeyError, TypeError, AttributeError):
        return False


@contextlib.asynccontextmanager
async def mqtt_probe(
    broker: BrokerAddress, *subscriptions: str, **connect: Any
) -> AsyncIterator[MqttProbe]:
    """`connect`: more of aiomqtt.Client's arguments (tls_context, username, password; an
    `identifier` with `clean_session=False` for a session the broker keeps while it is away).
    `qos`: the subscriptions', 1 unless given (0 for a dashboard that only reads state: on NATS
    a QoS 1 subscription is a replicated JetStream consumer, slow to set up)."""
    qos: int = connect.pop("qos", 1)
    identifier = connect.pop("identifier", f"probe-{uuid.uuid4().hex[:8]}")
    client = aiomqtt.Client(broker.host, broker.port, identifier=identifier, **connect)
    async with client:
        for topic in subscriptions:
            await client.subscribe(topic, qos=qos)
        probe = MqttProbe(client)
        task = asyncio.create_task(probe._collect(), name="mqtt-probe")
        try:
            yield probe
        finally:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError, aiomqtt.MqttError):
                await task


async def retained_messages(broker: BrokerAddress, topic_filter: str) -> dict[str, bytes]:
    """What a fresh subscriber to `topic_filter` (ending in `#`) is handed as retained, by
    topic: all of it arrives before a marker published under it after subscribing (one
    session, in order)."""
    marker = f"{topic_filter.rstrip('#/')}/marker-{uuid.uuid4().hex[:8]}"
    async with mqtt_probe(broker, topic_filter) as probe:
        await probe.publish(marker, "end")
        await probe.wait_for(marker)
        return {m.topic: m.payload for m in probe.messages if m.retain and m.payload}


class BrokerProxy:
    """A TCP relay in front of a broker, to break a client's connection at an exact point.

    `down()` and `up()` take the broker away from the relay's clients and give it back.
    `freeze()` holds back everything clients send (kept in `held`, never forwarded: a publish
    then waits for its acknowledgement); `cut()` closes every connection through the relay and
    lets new ones pass normally again. The broker and everyone connected to it directly notice
    nothing.
    """

    def __init__(self, broker: BrokerAddress) -> None:
        self.broker = broker
        self.host = "127.0.0.1"
        self.port = 0
        self.held = b""
        self._frozen = False
        self._held_changed = asyncio.Event()
        self._server: asyncio.Server | None = None
        self._writers: list[asyncio.StreamWriter] = []
        self._tasks: set[asyncio.Task[None]] = set()

    async def __aenter__(self) -> BrokerProxy:
        self._server = await asyncio.start_server(self._relay, self.host, 0)
        self.port = self._server.sockets[0].getsockname()[1]
        return self

    async def __aexit__(self, *exc_info: object) -> None:
        assert self._server is not None
        self._server.close()
        self.cut()
        for task in list(self._tasks):
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        await self._server.wait_closed()

    def down(self) -> None:
        """The broker gone, as its clients see it: every connection cut, new ones refused (the
        port closed) until `up`."""
        assert self._server is not None
        self._server.close()
        self.cut()

    async def up(self) -> None:
        """The broker back, on the same port."""
        self._server = await asyncio.start_server(self._relay, self.host, self.port)

    def freeze(self) -> None:
        self._frozen = True
        self.held = b""

    def cut(self) -> None:
        self._frozen = False
        for writer in self._writers:
            writer.transport.abort()  # a reset, as a broken cable or a dead router would give
        self._writers.clear()

    async def wait_held(self, needle: bytes, timeout_s: float = 10.0) -> None:
        """Until a frozen client has sent `needle`."""
        async with asyncio.timeout(timeout_s):
            while needle not in self.held:
                self._held_changed.clear()
                await self._held_changed.wait()

    async def _relay(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        broker_reader, broker_writer = await asyncio.open_connection(
            self.broker.host, self.broker.port
        )
        self._writers += [writer, broker_writer]
        for source, sink, outgoing in (
            (reader, broker_writer, True),
            (broker_reader, writer, False),
        ):
            task = asyncio.create_task(self._pump(source, sink, outgoing), name="broker-proxy")
            self._tasks.add(task)
            task.add_done_callback(self._tasks.discard)

    async def _pump(
        self, source: asyncio.StreamReader, sink: asyncio.StreamWriter, outgoing: bool
    ) -> None:
        with contextlib.suppress(OSError):
            while data := await source.read(65536):
                if outgoing and self._frozen:
                    self.held += data
                    self._held_changed.set()
                    continue
                sink.write(data)
                await sink.drain()
        sink.transport.abort()
