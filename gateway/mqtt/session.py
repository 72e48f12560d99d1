"""The bridge's connection to the broker: connect, back off, TLS, subscriptions, offline at stop.

    start    one named task runs the connection loop; start() returns at once (a broker that is
             down must never delay the gateway: Modbus-TCP serves without it)
    tls      the TLS context is built once, before the first attempt; a bad file is logged once,
             naming its key, and tried again with backoff (the loop never ends over it)
    connect  hand the client to `on_connect` (the bridge's session: what to publish, what to
             subscribe, the tasks that run while connected), which says online (`say_online`)
             once it is subscribed
    lost     any error ends the session; `on_lost`; wait (jittered, capped backoff), connect again
             to the next of `mqtt.servers` (a cluster's nodes, in turn)
    stop     say goodbye (`Presence.farewell`: the bridge's "offline", the Sparkplug edge
             node's NDEATH), end the loop
    leave    a presence that asks for it (`disconnect_with_will`: the Sparkplug edge node) ends
             every MQTT 5 connection it ends itself with reason code 0x04, "Disconnect with
             Will Message": the broker publishes the will then too

The last will is the `Presence`'s too, made anew for each attempt (Sparkplug's bdSeq counts
CONNECTs).

The session knows nothing of what is published or received: that is the publisher's and the
dispatcher's.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import ssl
import time
from collections.abc import Awaitable, Callable, Iterable
from dataclasses import dataclass
from typing import Protocol

import aiomqtt
from paho.mqtt.reasoncodes import ReasonCode
from paho.mqtt.subscribeoptions import SubscribeOptions

from gateway.backoff import Backoff
from gateway.errors import TlsSettingsError
from gateway.logs import repeated
from gateway.mqtt.connection import (
    MQTT_3_1_1,
    MQTT_5,
    OFFLINE,
    SUBSCRIBE_QOS,
    disconnect_with_will,
    make_client,
    online_payload,
    read_loss,
    server_name,
    tls_context,
)
from gateway.mqtt.stats import BridgeStats
from gateway.mqtt.topics import Topics
from gateway.settings import MqttSettings
from gateway.tasks import ServiceTasks, cancel_and_wait

log = logging.getLogger(__name__)

QOS = 1
UNSUPPORTED_PROTOCOL = frozenset({1, 0x84})
"""CONNACK's "unacceptable protocol version" (3.1.1) and "unsupported protocol version" (5)."""
RECONNECT_INITIAL_S = 0.5
STOP_PUBLISH_TIMEOUT_S = 0.3

OnConnect = Callable[[aiomqtt.Client], Awaitable[None]]


class Presence(Protocol):
    """How the connection tells the broker it is there, and gone: its last will (made anew for
    each attempt) and what it publishes itself at a clean stop (which sends no will).
    `disconnect_with_will`: an MQTT 5 connection ended on purpose asks the broker to publish the
    will all the same (reason code 0x04)."""

    disconnect_with_will: bool

    async def will(self) -> aiomqtt.Will: ...

    async def farewell(self, client: aiomqtt.Client, timeout_s: float) -> None: ...


@dataclass(frozen=True, slots=True)
class BridgeState:
    """The JSON bridge's presence: `<base>/bridge/state` "offline", retained."""

    topics: Topics
    disconnect_with_will = False
    """The farewell's retained "offline" is the will's: nothing more for the broker to say."""

    async def will(self) -> aiomqtt.Will:
        return aiomqtt.Will(self.topics.bridge_state, OFFLINE, qos=QOS, retain=True)

    async def farewell(self, client: aiomqtt.Client, timeout_s: float) -> None:
        await client.publish(
            self.topics.bridge_state, OFFLINE, qos=QOS, retain=True, timeout=timeout_s
        )


class Session:
    def __init__(
        self,
        mqtt: MqttSettings,
        topics: Topics,
        stats: BridgeStats,
        tasks: ServiceTasks,
        on_connect: OnConnect,
        on_lost: Callable[[], None],
        presence: Presence | None = None,
    ) -> None:
        self.mqtt = mqtt
        self.presence: Presence = presence or BridgeState(topics)
        self.topics = topics
        self.stats = stats
        self.tasks = tasks
        self.connected = asyncio.Event()
        """Set by the bridge once a connection is set up; cleared when it is lost."""
        self._on_connect = on_connect
        self._on_lost = on_lost
        self._client: aiomqtt.Client | None = None
        self._task: asyncio.Task[None] | None = None
        self.protocol = MQTT_5
        """MQTT 5 until the broker refuses it; then 3.1.1 for as long as the gateway runs."""
        self._settled = False
        """A connection has succeeded with `protocol`: it is the broker's."""
        self._tls: ssl.SSLContext | None = None
        self._stopping = False
        """Set by `stop`: the loop ends at its next turn, whatever swallowed the cancellation."""
        self.connected_since: float | None = None
        """Wall clock of the connection now up; None while there is none."""
        self.last_error: str | None = None
        """Why the last connection failed or was lost (kept after a reconnect: it happened)."""
        self.last_error_at: float | None = None
        self._server_index = 0
        """Which of `mqtt.servers` is in use, or tried next; the next one after each failure."""
        self._failures = 0
        """Connection attempts failed in a row (0 once connected)."""

    @property
    def server(self) -> tuple[str, int]:
        """The broker connected to, or the one the next attempt goes to."""
        return self.mqtt.servers[self._server_index]

    @property
    def server_name(self) -> str:
        return server_name(self.server)

    def server_names(self) -> list[str]:
        return [server_name(server) for server in self.mqtt.servers]

    async def start(self) -> None:
        self._stopping = False  # a reload stops the bridge and starts it again
        self._task = self.tasks.start("mqtt:bridge", self._run())

    async def say_offline(self) -> None:
        """A clean disconnect sends no last will: say "offline" ourselves, if connected."""
        client = self._client
        if client is not None:  # connected, maybe still setting up: online may be out
            with contextlib.suppress(aiomqtt.MqttError):
                await self.presence.farewell(client, STOP_PUBLISH_TIMEOUT_S)

    async def stop(self, budget_s: float) -> None:
        # Cancelling alone is not enough: when the connection breaks as the cancellation arrives,
        # `on_connect` can end with its tasks' MqttError instead of CancelledError; the loop would
        # take it for a lost connection and connect again, and outlive the cancel.
        self._stopping = True
        if self._task is not None:
            await cancel_and_wait(self._task, budget_s)
            self._task = None

    def side_client(self, purpose: str) -> aiomqtt.Client:
        """A second, short connection with the session's broker, TLS and protocol: its own
        client id (`<id>-<purpose>`), no last will. Call once the session has connected."""
        identifier = f"{self.mqtt.client_id}-{purpose}"
        return make_client(
            self.mqtt,
            self.topics,
            self._tls,
            self.server,
            self.protocol,
            identifier=identifier,
            will=False,
        )

    async def subscribe(
        self, client: aiomqtt.Client, topics: Iterable[str], qos: int = SUBSCRIBE_QOS
    ) -> None:
        """`qos`: the bridge's is `SUBSCRIBE_QOS` (why there); Sparkplug's edge node asks 1."""
        if self.protocol == MQTT_5:
            # Retain-as-published: a retained command keeps its flag when delivered live too,
            # so it is refused however it comes (under 3.1.1 the broker clears it).
            options = SubscribeOptions(qos=qos, retainAsPublished=True)
            await client.subscribe([(topic, options) for topic in topics])
            return
        await client.subscribe([(topic, qos) for topic in topics])

    async def _run(self) -> None:
        backoff = Backoff(RECONNECT_INITIAL_S, self.mqtt.reconnect_max_s)
        tls = self._tls = await self._tls_context(backoff)
        self._failures = 0
        while not self._stopping:
            retry_at_once = await self._connection(tls, backoff)
            if self._stopping:
                return
            if retry_at_once:
                continue
            # Whatever failed, the next broker of the list is tried (a cluster's node that
            # died may stay away; any node will do), after the backoff's wait.
            self._server_index = (self._server_index + 1) % len(self.mqtt.servers)
            await asyncio.sleep(backoff.next_delay())

    async def _connection(self, tls: ssl.SSLContext | None, backoff: Backoff) -> bool:
        """One connection to the broker, from the attempt to its loss. True: try again at once
        (the broker refused MQTT 5, and answered: 3.1.1 next)."""
        retry_at_once = False
        client: aiomqtt.Client | None = None
        try:
            # Inside the try: whatever building a client raises is one more failed attempt,
            # never the end of the loop.
            client = make_client(
                self.mqtt,
                self.topics,
                tls,
                self.server,
                self.protocol,
                last_will=await self.presence.will(),
            )
            async with client:
                self._client = client
                if self._failures:
                    log.info("MQTT: connected again after %d failed attempts", self._failures)
                self._failures = 0
                backoff.reset()
                try:
                    await self._connected(client)
                finally:
                    await self._leave(client)
        except* aiomqtt.MqttError as group:
            # Refused MQTT 5: again at once, in 3.1.1; the broker is there, it answered.
            # That is the negotiation of the protocol, not an error: Diagnostics showed
            # "Last error 132" (MQTT 5's "unsupported protocol version") on a healthy
            # 3.1.1 connection.
            retry_at_once = self._choose_protocol_after(group.exceptions[0])
            if not retry_at_once:
                self._log_failure(self._failed(group.exceptions[0]), group.exceptions[0])
        except* Exception as failure:
            # A bug, or a client that can't be built: not the broker, but the bridge must not
            # die of it either. The whole story once, then a line per attempt.
            if self._failed(failure.exceptions[0]) == 1:
                log.exception("MQTT bridge failed; retrying with backoff")
            else:
                log.debug("MQTT bridge failed again (attempt %d)", self._failures, exc_info=True)
        finally:
            if client is not None:
                read_loss(client)
            self._client = None
            self.connected_since = None
            self.connected.clear()
            self._on_lost()
        return retry_at_once

    async def _leave(self, client: aiomqtt.Client) -> None:
        """Before aiomqtt's own DISCONNECT (reason code 0): the presence's with its will, on
        MQTT 5 (a connection already lost sends nothing)."""
        if self.presence.disconnect_with_will and self.protocol == MQTT_5:
            await disconnect_with_will(client, STOP_PUBLISH_TIMEOUT_S)

    def _failed(self, error: BaseException) -> int:
        """One more failed attempt, noted for Diagnostics and counted; how many in a row."""
        self._note_error(error)
        self._failures += 1
        self.stats.connect_failures += 1
        return self._failures

    def _note_error(self, error: BaseException) -> None:
        self.last_error = str(error) or type(error).__name__
        self.last_error_at = time.time()

    def _choose_protocol_after(self, error: BaseException) -> bool:
        """After a failed attempt, before any succeeded: the protocol to try next. True: try it
        at once (the broker answered, it refused MQTT 5).

        MQTT 5 first, for retain-as-published. A broker that speaks only 3.1.1 either refuses it
        in its CONNACK, or (RabbitMQ 3.10) can't parse the CONNECT and closes the connection
        without a word: after a handshake that failed that way, the other protocol is tried.
        A broker that isn't there at all (refused, unreachable) teaches nothing: the protocol
        stays, so a Mosquitto that comes back later still gets MQTT 5.
        """
        if self._settled:
            return False
        if isinstance(error, aiomqtt.MqttCodeError):
            code = error.rc.value if isinstance(error.rc, ReasonCode) else error.rc
            if self.protocol == MQTT_5 and code in UNSUPPORTED_PROTOCOL:
                self.protocol = MQTT_3_1_1
                return True
            return False  # a CONNACK came: the broker read our CONNECT (credentials, ...)
        if "Errno" in str(error):
            return False  # no broker there: nothing learnt about its protocol
        self.protocol = MQTT_3_1_1 if self.protocol == MQTT_5 else MQTT_5
        return False

    def _settle(self) -> None:
        """A connection is up: its protocol is the broker's, for as long as the gateway runs."""
        if self._settled:
            return
        self._settled = True
        if self.protocol == MQTT_3_1_1:
            # Information, not a warning: 3.1.1 is a protocol the gateway fully works with (a
            # command that came retained all the same is cleared once it ran: the bridge's
            # dispatcher); the demo's own broker speaks it, and warned at every start.
            log.info(
                "MQTT: the broker %s speaks MQTT 3.1.1 (not 5): connected with 3.1.1",
                self.server_name,
            )

    async def _connected(self, client: aiomqtt.Client) -> None:
        self._settle()
        self.stats.connects += 1
        self.connected_since = time.time()
        log.info("MQTT: connected to %s as %s", self.server_name, self.mqtt.client_id)
        await self._on_connect(client)

    async def say_online(self, client: aiomqtt.Client) -> None:
        """Retained "online" on `bridge/state`: for `on_connect` to send once it listens to the
        request topics, so a client that acts on "online" is heard."""
        online = online_payload(self.mqtt, self.server)
        await client.publish(
            self.topics.bridge_state, online, qos=self.mqtt.publish_qos, retain=True
        )
        self.stats.published += 1

    async def _tls_context(self, backoff: Backoff) -> ssl.SSLContext | None:
        """Built once for every attempt; until the files are usable, tried again with backoff."""
        while True:
            try:
                tls = tls_context(self.mqtt)
            except TlsSettingsError as exc:
                self.stats.tls_failures += 1
                if self.stats.tls_failures == 1:
                    log.error(
                        "MQTT: %s; no connection to the broker until it is fixed "
                        "(checking again with backoff)",
                        exc,
                    )
                else:
                    log.debug("MQTT: %s (attempt %d)", exc, self.stats.tls_failures)
                await asyncio.sleep(backoff.next_delay())
                continue
            if self.stats.tls_failures:
                log.info("MQTT: the TLS files are usable now")
                backoff.reset()
            return tls

    def _log_failure(self, failures: int, exc: BaseException) -> None:
        # Loudly at once, then one line a minute with the number held back (`repeated`): a
        # broker down for a night must not flood the journal, and one that keeps refusing this
        # connection (NATS refuses the Sparkplug edge node's `spBv1.0` topics) must not go
        # silent after the first line either. Each connection (the bridge's, the edge node's)
        # is counted apart, by its client id.
        log.warning(
            "MQTT broker %s (client %s): %s; reconnecting with backoff (attempt %d)",
            self.server_name,
            self.mqtt.client_id,
            exc,
            failures,
            extra=repeated(f"mqtt-connect:{self.mqtt.client_id}"),
        )
