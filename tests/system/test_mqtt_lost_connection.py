"""A connection lost while the client waited for an acknowledgement leaves no asyncio noise.

aiomqtt keeps a lost connection's error in a future that only its message iterator reads; a
client lost while it waited for a PUBACK (a cluster's node that died, or closed the connection
because it could not store a QoS 1 message) left it unread, and asyncio printed "Future
exception was never retrieved ... MqttCodeError" in the gateway's log when the client was
dropped. `read_loss` reads it. Asserted on what asyncio decides that by (the future's
`_log_traceback`): when the client is dropped depends on the garbage collector.
"""

from __future__ import annotations

import asyncio

import aiomqtt
import pytest

from gateway.mqtt.connection import read_loss
from tests.support.mosquitto import BrokerProxy, Mosquitto, unique_base_topic


async def lost_waiting_for_an_acknowledgement(relay: BrokerProxy) -> aiomqtt.Client:
    """A client publishes at QoS 1 through a frozen relay; the connection is cut meanwhile."""
    client = aiomqtt.Client(relay.host, relay.port, identifier=unique_base_topic("lost"))
    async with client:
        relay.freeze()
        publishing = asyncio.create_task(
            client.publish(f"{unique_base_topic()}/state", b"1", qos=1, timeout=2)
        )
        await relay.wait_held(b"/state")
        relay.cut()
        with pytest.raises(aiomqtt.MqttError):
            await publishing  # "Operation timed out": aiomqtt's publish doesn't see the loss
    return client


def would_be_printed(client: aiomqtt.Client) -> bool:
    """asyncio prints "Future exception was never retrieved" for it once it is dropped."""
    lost = client._disconnected  # what asyncio's noise is about
    return lost.done() and bool(lost._log_traceback)


async def test_a_loss_read_by_read_loss_leaves_nothing_to_print(mosquitto: Mosquitto) -> None:
    async with BrokerProxy(mosquitto) as relay:
        client = await lost_waiting_for_an_acknowledgement(relay)
    read_loss(client)
    assert isinstance(client._disconnected.exception(), aiomqtt.MqttCodeError)
    assert not would_be_printed(client)


async def test_aiomqtt_alone_would_leave_it_to_be_printed(mosquitto: Mosquitto) -> None:
    """What `read_loss` is for (this fails the day aiomqtt reads the loss itself; then it
    can go)."""
    async with BrokerProxy(mosquitto) as relay:
        client = await lost_waiting_for_an_acknowledgement(relay)
    assert would_be_printed(client)
