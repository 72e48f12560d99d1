"""A drive's nodes deleted at a reload, their subscribers told or kept.

asyncua 2.1's DeleteNodes calls each deleted node's data-change callbacks without awaiting
them (they are coroutines): no subscriber hears of it, and Python warns of a coroutine never
awaited. So the gateway takes the callbacks (the clients' monitored items) off the nodes
first, then deletes them, and then either

    tells them          the drive is gone: each item's last value is BadNodeIdUnknown, as OPC
                        UA has it, and the item stays in its subscription until the client
                        deletes it
    reattaches them     the drive was changed (its keys, its model): its nodes are made again
                        with the same NodeIds, and each item goes on with the new node of its
                        NodeId, so a client's subscription to it keeps receiving

Reattaching writes asyncua's own table of which node a callback handle belongs to: asyncua has
no call that moves a monitored item to another node.
"""

from __future__ import annotations

import datetime
from collections.abc import Awaitable, Callable

from asyncua import Node, Server, ua

from gateway.opcua.values import status_value

Callback = Callable[..., Awaitable[None]]
Detached = dict[ua.NodeId, dict[int, Callback]]
"""Each node's data-change callbacks (its monitored items), by handle."""


async def subtree(node: Node) -> list[Node]:
    """`node` and every node below it (hierarchical references: children and properties)."""
    found = [node]
    for child in await node.get_children():
        found += await subtree(child)
    return found


async def detach_and_delete(server: Server, top: ua.NodeId) -> Detached:
    """`top` and the nodes below it deleted; their monitored items' callbacks, taken off."""
    nodes = await subtree(server.get_node(top))
    aspace = server.iserver.aspace
    detached: Detached = {}
    for node in nodes:
        data = aspace.get(node.nodeid)
        value = data.attributes.get(ua.AttributeIds.Value) if data is not None else None
        if value is None or not value.datachange_callbacks:
            continue
        detached[node.nodeid] = dict(value.datachange_callbacks)
        for handle in list(value.datachange_callbacks):
            aspace.delete_datachange_callback(handle)
    await server.delete_nodes(nodes)
    return detached


async def tell_gone(detached: Detached) -> None:
    gone = status_value(ua.StatusCodes.BadNodeIdUnknown, datetime.datetime.now(datetime.UTC))
    for callbacks in detached.values():
        for handle, callback in callbacks.items():
            await callback(handle, gone)


def reattach(server: Server, detached: Detached) -> Detached:
    """Each callback onto the node of its NodeId made again; those whose node is not, back."""
    aspace = server.iserver.aspace
    left: Detached = {}
    for node_id, callbacks in detached.items():
        data = aspace.get(node_id)
        value = data.attributes.get(ua.AttributeIds.Value) if data is not None else None
        if value is None:
            left[node_id] = callbacks
            continue
        for handle, callback in callbacks.items():
            value.datachange_callbacks[handle] = callback
            aspace._handle_to_attribute_map[handle] = (node_id, ua.AttributeIds.Value)
    return left
