"""How the bridge connects: client id, TLS, last will, and the backoff between attempts.

aiomqtt has no automatic reconnect; its documented pattern is a loop around `async with client`
catching `MqttError`, which the bridge follows with a fresh client for every attempt (so no
message received on a lost connection is ever handled after the next one). Between attempts the
wait doubles up to a cap, with jitter, so gateways that lost one broker together don't all come
back in the same instant.
"""

from __future__ import annotations

import json
import random
import ssl

import aiomqtt

from gateway.config import GatewayConfig, MqttConfig
from gateway.mqtt.topics import Topics

ONLINE = json.dumps({"state": "online"}, separators=(",", ":"))
OFFLINE = json.dumps({"state": "offline"}, separators=(",", ":"))
CONNECT_TIMEOUT_S = 5.0
"""Connecting, subscribing, and waiting for a QoS 1 acknowledgement."""


def client_id(config: GatewayConfig) -> str:
    """Unique per gateway: two with the same id would throw each other off the broker."""
    assert config.mqtt is not None
    return config.mqtt.client_id or f"invt-gateway-{config.gateway_id}"


def tls_context(mqtt: MqttConfig) -> ssl.SSLContext | None:
    if not mqtt.tls:
        return None
    context = ssl.create_default_context(cafile=mqtt.ca_file)
    if mqtt.cert_file is not None:
        context.load_cert_chain(mqtt.cert_file, mqtt.key_file)
    return context


def make_client(config: GatewayConfig, topics: Topics) -> aiomqtt.Client:
    mqtt = config.mqtt
    assert mqtt is not None
    return aiomqtt.Client(
        mqtt.host,
        mqtt.port,
        username=mqtt.username,
        password=mqtt.password,
        identifier=client_id(config),
        # The broker says "offline" for us if we vanish (power cut, kill -9, cable).
        will=aiomqtt.Will(topics.bridge_state, OFFLINE, qos=1, retain=True),
        # No session kept on the broker: commands sent while we were away are not delivered
        # later, when the plant may be in another state.
        clean_session=True,
        keepalive=mqtt.keepalive_s,
        timeout=CONNECT_TIMEOUT_S,
        tls_context=tls_context(mqtt),
    )


class Backoff:
    def __init__(self, initial_s: float, max_s: float, rng: random.Random | None = None) -> None:
        self.initial_s = initial_s
        self.max_s = max_s
        self._delay_s = initial_s
        self._rng = rng or random.Random()

    def next_delay(self) -> float:
        """The wait before the next attempt: jittered, then doubled for the one after."""
        delay = self._delay_s * self._rng.uniform(0.5, 1.0)
        self._delay_s = min(self._delay_s * 2, self.max_s)
        return delay

    def reset(self) -> None:
        self._delay_s = self.initial_s
