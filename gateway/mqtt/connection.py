"""How the bridge connects: client id, TLS, last will, and the backoff between attempts.

aiomqtt has no automatic reconnect; its documented pattern is a loop around `async with client`
catching `MqttError`, which the bridge follows with a fresh client for every attempt (so no
message received on a lost connection is ever handled after the next one). Between attempts the
wait doubles up to a cap, with jitter (`gateway.backoff`), so gateways that lost one broker
together don't all come back in the same instant.

The TLS context is built once, from the files named in the configuration, and then shared by
every attempt. A file that exists but isn't what it should be (validation only checks that it can
be read) is a `TlsSettingsError` naming the key: the bridge says so loudly and tries again later,
so a certificate put right on disk is picked up without a restart.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import ssl

import aiomqtt
from paho.mqtt.client import MQTT_CLEAN_START_FIRST_ONLY, MQTT_ERR_SUCCESS
from paho.mqtt.client import Client as PahoClient
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.reasoncodes import ReasonCode

from gateway.errors import TlsSettingsError
from gateway.mqtt.topics import Topics
from gateway.settings import MqttSettings

ONLINE = json.dumps({"state": "online"}, separators=(",", ":"))
OFFLINE = json.dumps({"state": "offline"}, separators=(",", ":"))


def server_name(server: tuple[str, int]) -> str:
    """`host:port` as the configuration writes it (an IPv6 address in brackets)."""
    host, port = server
    return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"


def online_payload(mqtt: MqttSettings, server: tuple[str, int]) -> str:
    """`bridge/state` while connected: online, through which broker, and whose it is (a second
    gateway on the same base topic or client id finds it at its start)."""
    state = {
        "state": "online",
        "server": server_name(server),
        "gateway_id": mqtt.gateway_id,
        "client_id": mqtt.client_id,
    }
    return json.dumps(state, separators=(",", ":"))


CONNECT_TIMEOUT_S = 5.0
"""Connecting, subscribing, and waiting for a QoS 1 acknowledgement."""

SUBSCRIBE_QOS = 0
"""Every subscription the gateway makes (requests, commands, the start's checks) asks for QoS 0.

Our sessions are clean: what the broker holds for us dies with the connection, so QoS 1 on the
way in would add nothing a live TCP connection doesn't already give. It costs a lot on a NATS
cluster, though: there each QoS 1 subscription is a JetStream consumer replicated on
`stream_replicas` nodes, created one after another while the broker reads the SUBSCRIBE (about
0.4 s each on a healthy three-node cluster, up to NATS's 4 s API timeout each while a node is
down and its raft groups elect new leaders). A gateway with a few drives then missed
`CONNECT_TIMEOUT_S`, reconnected to another node (throwing its half-made session off the
first), and never got back while the node stayed down. At QoS 0 a subscription is plain NATS
interest: the node answers at once. At most once, too: no command is delivered twice.
"""


def tls_context(mqtt: MqttSettings) -> ssl.SSLContext | None:
    """The client's TLS context, or None without TLS. Raises TlsSettingsError."""
    if not mqtt.tls:
        return None
    try:
        context = ssl.create_default_context(cafile=mqtt.ca_file)
    except (ssl.SSLError, OSError) as exc:
        key = "mqtt.ca_file" if mqtt.ca_file is not None else "the system's CA certificates"
        raise TlsSettingsError(key, mqtt.ca_file, _reason(exc, "no CA certificate")) from None
    if mqtt.cert_file is not None:
        key = "mqtt.cert_file" if mqtt.key_file is None else "mqtt.cert_file/mqtt.key_file"
        path = mqtt.cert_file if mqtt.key_file is None else f"{mqtt.cert_file}, {mqtt.key_file}"

        def no_passphrase() -> str:
            # Without a callback OpenSSL would prompt on the terminal, blocking the event loop;
            # what the callback raises comes out of load_cert_chain as it is.
            reason = "the private key is encrypted: give it without a passphrase"
            raise TlsSettingsError(key, path, reason)

        try:
            context.load_cert_chain(mqtt.cert_file, mqtt.key_file, password=no_passphrase)
        except (ssl.SSLError, OSError) as exc:
            reason = _reason(exc, "not a PEM certificate and its private key")
            raise TlsSettingsError(key, path, reason) from None
    return context


def _reason(exc: ssl.SSLError | OSError, hint: str) -> str:
    if not isinstance(exc, ssl.SSLError):
        return str(exc.strerror or exc).lower()  # "no such file or directory": it went away
    # OpenSSL's "PEM lib" says nothing to a person: say what the file should have been.
    text = str(exc.reason or exc.strerror or exc)
    return hint if "PEM lib" in text else f"{hint} ({text.replace('_', ' ').lower()})"


MQTT_5 = aiomqtt.ProtocolVersion.V5
MQTT_3_1_1 = aiomqtt.ProtocolVersion.V311


def make_client(
    mqtt: MqttSettings,
    topics: Topics,
    tls: ssl.SSLContext | None,
    server: tuple[str, int],
    protocol: aiomqtt.ProtocolVersion = MQTT_3_1_1,
    identifier: str | None = None,
    will: bool = True,
    last_will: aiomqtt.Will | None = None,
) -> aiomqtt.Client:
    """A fresh client for one connection attempt to `server` (one of `mqtt.servers`); `tls`
    from `tls_context`, built once, for every server alike.

    MQTT 5 where the broker speaks it: only there does a subscription keep the retain flag of a
    message delivered live (retain-as-published), so a retained command can always be refused.
    `last_will`: another will than the bridge's "offline" (the Sparkplug edge node's NDEATH).
    """
    five = protocol == MQTT_5
    if will and last_will is None:
        last_will = aiomqtt.Will(topics.bridge_state, OFFLINE, qos=1, retain=True)
    return aiomqtt.Client(
        server[0],
        server[1],
        username=mqtt.username,
        password=mqtt.password,
        identifier=identifier or mqtt.client_id,
        # The broker says "offline" for us if we vanish (power cut, kill -9, cable). A side
        # connection (`will=False`) must not: the gateway is still there.
        will=last_will if will else None,
        # No session kept on the broker: commands sent while we were away are not delivered
        # later, when the plant may be in another state. (MQTT 5: a clean start, and a
        # session that ends with the connection, the default expiry of 0.)
        clean_session=None if five else True,
        clean_start=True if five else MQTT_CLEAN_START_FIRST_ONLY,
        protocol=protocol,
        keepalive=mqtt.keepalive_s,
        timeout=CONNECT_TIMEOUT_S,
        tls_context=tls,
    )


def read_loss(client: aiomqtt.Client) -> None:
    """Read the error of a connection that was lost (the broker closed it, or died) out of the
    future aiomqtt keeps it in: call once the client's `async with` is left.

    aiomqtt reads it only where something awaited the loss (its message iterator); a client
    lost while it waited for a PUBACK or a SUBACK (a cluster's node that died, or closed the
    connection because it could not store a QoS 1 message) leaves it there, and asyncio then
    prints "Future exception was never retrieved ... MqttCodeError" when the client is
    dropped. The loss is handled already (the connection is made again): reading it is all
    that is left to do. `_disconnected` is aiomqtt's (2.x); if it goes, this does nothing, and
    `tests/system/test_mqtt_lost_connection.py` says so.
    """
    lost = getattr(client, "_disconnected", None)
    if isinstance(lost, asyncio.Future) and lost.done() and not lost.cancelled():
        lost.exception()


DISCONNECT_WITH_WILL = 0x04
"""MQTT 5's DISCONNECT reason code "Disconnect with Will Message": the server publishes the will."""


async def disconnect_with_will(client: aiomqtt.Client, timeout_s: float) -> bool:
    """End an MQTT 5 connection with a DISCONNECT whose reason code is 0x04, "Disconnect with
    Will Message" (the Sparkplug edge node's clean stop: specification 3.0,
    `payloads-ndeath-will-message-publisher-disconnect-mqtt50`); True once it is sent.

    aiomqtt (2.5) sends its DISCONNECT without a reason code and takes none, so this asks paho,
    the client under it (`_client`), and waits for the loss it reports (`_disconnected`): once
    that is done, aiomqtt's `async with` sends nothing more. If either goes from aiomqtt, this
    returns False and the connection ends with aiomqtt's own DISCONNECT;
    `tests/system/test_sparkplug_death_and_host.py` says so (the broker's will no longer comes).
    """
    paho = getattr(client, "_client", None)
    lost = getattr(client, "_disconnected", None)
    if not isinstance(paho, PahoClient) or not isinstance(lost, asyncio.Future):
        return False
    reason = ReasonCode(PacketTypes.DISCONNECT, identifier=DISCONNECT_WITH_WILL)
    if paho.disconnect(reasoncode=reason) != MQTT_ERR_SUCCESS:
        return False
    # Gone either way (a timeout, or the loss aiomqtt reports): `read_loss` reads what it was.
    with contextlib.suppress(TimeoutError, aiomqtt.MqttError):
        await asyncio.wait_for(asyncio.shield(lost), timeout_s)
    return True
