"""MQTT for `invt-gateway demo`: a broker if none is running, and a console to watch it.

The demo uses the broker at the configured host and port when one answers there; when none does
and the host is this machine, it starts the embedded broker in its place (on another free port
if that one is taken), so telemetry can be watched on a fresh machine with nothing installed.
"""

from __future__ import annotations

import asyncio
import contextlib
import ipaddress
import logging
import sys
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from typing import Final, TextIO

import aiomqtt

from gateway.config import MqttConfig
from gateway.instruments.embedded_broker import EmbeddedBroker
from gateway.mqtt.discovery_cleanup import own_discovery_topics, remove_stale_entities

log = logging.getLogger(__name__)

PROBE_TIMEOUT_S: Final = 1.0
WATCH_RETRY_S: Final = 1.0
CLEAR_TIMEOUT_S: Final = 10.0
"""Connecting, collecting the retained configs (a second) and clearing them, at most."""


@dataclass(frozen=True)
class DemoBroker:
    config: MqttConfig
    """The MQTT settings to run with (the port may have changed to the embedded broker's)."""
    embedded: EmbeddedBroker | None
    note: str
    """One line for the banner: which broker, and why."""


async def broker_for_demo(mqtt: MqttConfig) -> DemoBroker:
    where = f"{mqtt.host}:{mqtt.port}"
    if await _answers(mqtt.host, mqtt.port):
        return DemoBroker(mqtt, None, f"MQTT broker at {where} (already running)")
    if not _is_local(mqtt.host):
        return DemoBroker(mqtt, None, f"MQTT broker at {where} not reachable: retrying")
    broker = EmbeddedBroker("127.0.0.1", mqtt.port)
    try:
        await broker.start()
    except OSError:
        broker = EmbeddedBroker("127.0.0.1", 0)  # the port is taken by something else
        await broker.start()
    config = mqtt.model_copy(update={"host": "127.0.0.1", "port": broker.port})
    note = f"MQTT broker at 127.0.0.1:{broker.port} (embedded: none was running at {where})"
    return DemoBroker(config, broker, note)


async def clear_discovery(mqtt: MqttConfig, gateway_id: str) -> None:
    """Clear the demo's Home Assistant discovery configs from the broker, once it has stopped.

    They are retained: on a shared broker (a plant's, or a developer's Mosquitto) every demo
    run would leave its entities in Home Assistant for good. The embedded broker needs none of
    this: it goes with the demo. A demo stopped by SIGKILL leaves them; the next start of a
    gateway with the same `gateway_id` (and discovery off) clears them.
    """
    if not mqtt.homeassistant_discovery:
        return
    where = f"{mqtt.host}:{mqtt.port}"
    client = aiomqtt.Client(
        mqtt.host,
        mqtt.port,
        identifier=f"invt-gateway-{gateway_id}-{uuid.uuid4().hex[:8]}-cleanup",
        username=mqtt.username,
        password=mqtt.password,
        timeout=CLEAR_TIMEOUT_S / 2,
    )
    pattern = own_discovery_topics(mqtt.discovery_prefix, gateway_id)
    try:
        async with asyncio.timeout(CLEAR_TIMEOUT_S):
            cleared = await remove_stale_entities(client, pattern, offered=())
    except (aiomqtt.MqttError, TimeoutError) as exc:
        log.warning("demo: its Home Assistant discovery configs stay on %s: %s", where, exc)
        return
    log.info("demo: cleared its %d Home Assistant discovery configs from %s", len(cleared), where)


async def _answers(host: str, port: int) -> bool:
    try:
        _, writer = await asyncio.wait_for(asyncio.open_connection(host, port), PROBE_TIMEOUT_S)
    except (OSError, TimeoutError):
        return False
    writer.close()
    with contextlib.suppress(OSError):
        await writer.wait_closed()
    return True


def _is_local(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


async def watch_messages(
    mqtt: MqttConfig,
    topic: str,
    out: TextIO = sys.stdout,
    on_line: Callable[[str], None] | None = None,
    status: TextIO | None = None,
) -> None:
    """Print every message on `topic` as `topic payload`, as `mosquitto_sub -v` does; forever.

    With `status`, says there when it is watching and, once per outage, when no broker answers
    (the demo isn't running yet, or was stopped): it keeps trying until cancelled.
    """
    # Its own client id every time: a watcher must never throw another client off the broker.
    client_id = f"invt-gateway-watch-{uuid.uuid4().hex[:8]}"
    where = f"{mqtt.host}:{mqtt.port}"
    waiting = False
    while True:
        try:
            async with aiomqtt.Client(
                mqtt.host,
                mqtt.port,
                identifier=client_id,
                username=mqtt.username,
                password=mqtt.password,
            ) as client:
                await client.subscribe(topic)
                waiting = False
                if status is not None:
                    print(f"watching {topic} at {where} (Ctrl-C to stop)", file=status, flush=True)
                async for message in client.messages:
                    payload = message.payload
                    text = (
                        payload.decode(errors="replace")
                        if isinstance(payload, bytes)
                        else str(payload)
                    )
                    line = f"{message.topic} {text}"
                    print(line, file=out, flush=True)
                    if on_line is not None:
                        on_line(line)
        except aiomqtt.MqttError as exc:
            log.debug("watch: %s; retrying", exc)
            if status is not None and not waiting:
                print(
                    f"no MQTT broker answers at {where} ({exc}): is `invt-gateway demo` "
                    "running? waiting for it",
                    file=status,
                    flush=True,
                )
            waiting = True
        await asyncio.sleep(WATCH_RETRY_S)
