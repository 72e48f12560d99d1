"""A tiny MQTT 3.1.1 broker for `invt-gateway demo` on a machine that has none. Loopback only.

Why our own, ~250 lines, rather than a package: the demo must work on a fresh machine with nothing
but `pip install invt-gateway`. The Python broker on PyPI (amqtt 0.12) would add eight runtime
dependencies to every installation, among them an exact pin of websockets and argon2 bindings, for
a feature only the demo uses; the mosquitto binary is not on a fresh machine. The subset the demo
needs is small and fully specified by MQTT 3.1.1: CONNECT with a last will, PUBLISH (QoS 0, 1 and
2 accepted), retained messages, SUBSCRIBE with `+`/`#` wildcards, UNSUBSCRIBE, PINGREQ, DISCONNECT.

Not for production: no authentication, no persistence, no TLS, every delivery at QoS 0 (granted
as such in SUBACK, which the protocol allows). Point a real gateway at Mosquitto, EMQX or HiveMQ.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import struct
import uuid
from dataclasses import dataclass, field
from typing import Final

from gateway.errors import MalformedPacket

log = logging.getLogger(__name__)

CONNECT, CONNACK, PUBLISH, PUBACK, PUBREC, PUBREL, PUBCOMP = 1, 2, 3, 4, 5, 6, 7
SUBSCRIBE, SUBACK, UNSUBSCRIBE, UNSUBACK, PINGREQ, PINGRESP, DISCONNECT = 8, 9, 10, 11, 12, 13, 14
MQTT_311: Final = 4
UNACCEPTABLE_PROTOCOL: Final = 1
MAX_PACKET: Final = 1 << 20
MAX_BUFFERED: Final = 4 << 20
"""A subscriber this far behind is disconnected rather than buffered without bound."""


@dataclass(eq=False)
class Session:
    client_id: str
    writer: asyncio.StreamWriter
    subscriptions: set[str] = field(default_factory=set)
    will: tuple[str, bytes, bool] | None = None

    def send(self, packet: bytes) -> None:
        transport = self.writer.transport
        if transport.is_closing():
            return
        if transport.get_write_buffer_size() > MAX_BUFFERED:
            log.warning("embedded broker: %s too slow, disconnected", self.client_id)
            transport.abort()
            return
        self.writer.write(packet)


STOP_S = 5.0
"""The most a stop waits for the listening socket to close once every client is gone."""


class EmbeddedBroker:
    def __init__(self, host: str = "127.0.0.1", port: int = 1883) -> None:
        self.host = host
        self.port = port
        self.retained: dict[str, bytes] = {}
        self.sessions: dict[str, Session] = {}
        self._server: asyncio.Server | None = None
        self._connections: set[asyncio.Task[None]] = set()

    async def start(self) -> None:
        self._server = await asyncio.start_server(self._connection, self.host, self.port)
        self.port = self._server.sockets[0].getsockname()[1]
        log.info("embedded MQTT broker on %s:%d (demo only)", self.host, self.port)

    async def stop(self) -> None:
        # The clients' connections first: a server's wait_closed may wait for every connection
        # to end (uvloop's does), and a client that stays connected would hold the stop forever.
        if self._server is not None:
            self._server.close()
        for task in list(self._connections):
            task.cancel()
        await asyncio.gather(*self._connections, return_exceptions=True)
        if self._server is not None:
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._server.wait_closed(), STOP_S)

    # -- one client --------------------------------------------------------------------------

    async def _connection(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._connections.add(task)
        session: Session | None = None
        try:
            session, keepalive = await self._connect(reader, writer)
            # The spec: a client silent for 1.5 keepalive periods is gone (its will is sent).
            timeout = keepalive * 1.5 if keepalive else None
            while True:
                kind, flags, body = await asyncio.wait_for(read_packet(reader), timeout)
                if kind == DISCONNECT:
                    session.will = None
                    return
                self._handle(session, kind, flags, body)
                await writer.drain()
        except (MalformedPacket, asyncio.IncompleteReadError, ConnectionError, TimeoutError) as exc:
            log.debug("embedded broker: connection closed: %r", exc)
        finally:
            self._connections.discard(task)
            if session is not None:
                self._disconnected(session)
            writer.close()

    async def _connect(
        self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter
    ) -> tuple[Session, int]:
        kind, _, body = await asyncio.wait_for(read_packet(reader), 10)
        if kind != CONNECT:
            raise MalformedPacket("the first packet must be CONNECT")
        fields = Fields(body)
        fields.string()  # "MQTT"
        level, flags = fields.byte(), fields.byte()
        if level != MQTT_311:
            writer.write(bytes((CONNACK << 4, 2, 0, UNACCEPTABLE_PROTOCOL)))
            await writer.drain()
            raise MalformedPacket(f"protocol level {level}: only MQTT 3.1.1 (4)")
        keepalive = fields.short()
        client_id = fields.string() or f"anonymous-{uuid.uuid4().hex[:8]}"
        will = None
        if flags & 0x04:
            will_topic = fields.string()
            will = (will_topic, fields.binary(), bool(flags & 0x20))
        # Username and password (flags 0x80, 0x40) are read by nobody: loopback, demo only.
        previous = self.sessions.get(client_id)
        if previous is not None:  # the spec: a second connection with the same id wins
            previous.writer.transport.abort()
        session = Session(client_id, writer, will=will)
        self.sessions[client_id] = session
        writer.write(bytes((CONNACK << 4, 2, 0, 0)))
        await writer.drain()
        return session, keepalive

    def _disconnected(self, session: Session) -> None:
        if self.sessions.get(session.client_id) is session:
            del self.sessions[session.client_id]
        if session.will is not None:
            topic, payload, retain = session.will
            self.publish(topic, payload, retain)

    def _handle(self, session: Session, kind: int, flags: int, body: bytes) -> None:
        fields = Fields(body)
        if kind == PUBLISH:
            qos, retain = (flags >> 1) & 0x03, bool(flags & 0x01)
            topic = fields.string()
            if qos:
                packet_id = fields.short()
                answer = PUBACK if qos == 1 else PUBREC
                session.send(struct.pack(">BBH", answer << 4, 2, packet_id))
            self.publish(topic, fields.rest(), retain)
        elif kind == PUBREL:
            session.send(struct.pack(">BBH", PUBCOMP << 4, 2, fields.short()))
        elif kind == SUBSCRIBE:
            packet_id = fields.short()
            filters = []
            while not fields.done():
                filters.append(fields.string())
                fields.byte()  # requested QoS: every delivery is QoS 0 here
            session.send(encode(SUBACK << 4, struct.pack(">H", packet_id) + bytes(len(filters))))
            for topic_filter in filters:
                session.subscriptions.add(topic_filter)
                for topic, payload in self.retained.items():
                    if topic_matches(topic_filter, topic):
                        session.send(publish_packet(topic, payload, retain=True))
        elif kind == UNSUBSCRIBE:
            packet_id = fields.short()
            while not fields.done():
                session.subscriptions.discard(fields.string())
            session.send(struct.pack(">BBH", UNSUBACK << 4, 2, packet_id))
        elif kind == PINGREQ:
            session.send(bytes((PINGRESP << 4, 0)))
        elif kind not in (PUBACK, PUBREC, PUBCOMP):
            raise MalformedPacket(f"unexpected packet type {kind}")

    def publish(self, topic: str, payload: bytes, retain: bool) -> None:
        if retain:
            if payload:
                self.retained[topic] = payload
            else:
                self.retained.pop(topic, None)  # an empty retained message clears it
        packet = publish_packet(topic, payload, retain=False)
        for session in list(self.sessions.values()):
            if any(topic_matches(f, topic) for f in session.subscriptions):
                session.send(packet)


def topic_matches(topic_filter: str, topic: str) -> bool:
    """MQTT wildcards: `+` one level, `#` the rest (the parent too); `$...` topics not by them."""
    if topic.startswith("$") and topic_filter[:1] in ("+", "#"):
        return False
    filter_levels, levels = topic_filter.split("/"), topic.split("/")
    for index, level in enumerate(filter_levels):
        if level == "#":
            return True
        if index >= len(levels) or level not in ("+", levels[index]):
            return False
    return len(filter_levels) == len(levels)


async def read_packet(reader: asyncio.StreamReader) -> tuple[int, int, bytes]:
    """(packet type, flags, body) of the next packet."""
    first = (await reader.readexactly(1))[0]
    length, multiplier = 0, 1
    for _ in range(4):
        byte = (await reader.readexactly(1))[0]
        length += (byte & 0x7F) * multiplier
        if not byte & 0x80:
            break
        multiplier *= 128
    else:
        raise MalformedPacket("remaining length longer than 4 bytes")
    if length > MAX_PACKET:
        raise MalformedPacket(f"packet of {length} bytes is over the {MAX_PACKET} limit")
    return first >> 4, first & 0x0F, await reader.readexactly(length)


def encode(first: int, body: bytes) -> bytes:
    length, encoded = len(body), bytearray()
    while True:
        byte, length = length % 128, length // 128
        encoded.append(byte | (0x80 if length else 0))
        if not length:
            return bytes((first, *encoded)) + body


def publish_packet(topic: str, payload: bytes, retain: bool) -> bytes:
    name = topic.encode()
    return encode((PUBLISH << 4) | int(retain), struct.pack(">H", len(name)) + name + payload)


class Fields:
    """Reads a packet body: bytes, 16-bit numbers, length-prefixed strings."""

    def __init__(self, body: bytes) -> None:
        self._body = body
        self._at = 0

    def _take(self, count: int) -> bytes:
        if self._at + count > len(self._body):
            raise MalformedPacket("packet shorter than its fields")
        chunk = self._body[self._at : self._at + count]
        self._at += count
        return chunk

    def byte(self) -> int:
        return self._take(1)[0]

    def short(self) -> int:
        value: int = struct.unpack(">H", self._take(2))[0]
        return value

    def binary(self) -> bytes:
        return self._take(self.short())

    def string(self) -> str:
        try:
            return self.binary().decode()
        except UnicodeDecodeError:
            raise MalformedPacket("a string that is not UTF-8") from None

    def rest(self) -> bytes:
        return self._take(len(self._body) - self._at)

    def done(self) -> bool:
        return self._at >= len(self._body)
