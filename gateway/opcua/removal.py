"""A drive's nodes deleted at a reload, its subscribers told.

asyncua 2.1's DeleteNodes calls each deleted node's data-change callbacks without awaiting
them (they are coroutines): no subscriber hears of it, and Python warns of a coroutine never
awaited. So the gateway tells them first, as OPC UA has it (the item's value goes to
BadNodeIdUnknown), through the ordinary, awaited write; takes the callbacks off; then deletes
the nodes, whose monitored items stay in the client's subscription until it deletes them.
"""

from __future__ import annotations

import datetime

from asyncua import Node, Server, ua

from gateway.opcua.values import status_value


async def subtree(node: Node) -> list[Node]:
    """`node` and every node below it (hierarchical references: children and properties)."""
    found = [node]
    for child in await node.get_children():
        found += await subtree(child)
    return found


async def delete_subtree(server: Server, top: ua.NodeId) -> None:
    nodes = await subtree(server.get_node(top))
    aspace = server.iserver.aspace
    gone = status_value(ua.StatusCodes.BadNodeIdUnknown, datetime.datetime.now(datetime.UTC))
    for node in nodes:
        data = aspace.get(node.nodeid)
        value = data.attributes.get(ua.AttributeIds.Value) if data is not None else None
        if value is None or not value.datachange_callbacks:
            continue
        await server.write_attribute_value(node.nodeid, gone)
        for handle in list(value.datachange_callbacks):
            aspace.delete_datachange_callback(handle)
    await server.delete_nodes(nodes)
