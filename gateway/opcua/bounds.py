"""The bound asyncua lacks: monitored items per session (`opcua.max_monitored_items`).

asyncua bounds connections (`max_connections`; it holds one session per connection, so that
bounds sessions too), subscriptions across the server (`max_subscriptions`), each monitored
item's queue and each subscription's unacknowledged messages; not how many items one session
may monitor, each of which the server keeps and samples. Past the bound, a CreateMonitoredItems
request gets its items made up to it and BadTooManyMonitoredItems for each beyond.
"""

from __future__ import annotations

import logging
from typing import Any

from asyncua import ua
from asyncua.server.subscription_service import SubscriptionService

from gateway.logs import repeated

log = logging.getLogger(__name__)


def monitored_items_of(service: SubscriptionService, session_id: ua.NodeId) -> int:
    return sum(
        len(subscription.monitored_item_srv._monitored_items)
        for subscription in service.subscriptions.values()
        if subscription.session_id == session_id
    )


def bound_monitored_items(service: SubscriptionService, per_session: int) -> None:
    """`service.create_monitored_items` from now on refuses what is beyond `per_session`."""
    create = service.create_monitored_items

    async def bounded(params: ua.CreateMonitoredItemsParameters) -> list[Any]:
        subscription = service.subscriptions.get(params.SubscriptionId)
        if subscription is None:
            return list(await create(params))  # asyncua's own answer to a wrong id
        asked = list(params.ItemsToCreate)
        room = max(0, per_session - monitored_items_of(service, subscription.session_id))
        if len(asked) <= room:
            return list(await create(params))
        log.warning(
            "OPC UA: a session asked for %d monitored items more, %d more allowed "
            "(opcua.max_monitored_items: %d): BadTooManyMonitoredItems for the rest",
            len(asked),
            room,
            per_session,
            extra=repeated("opcua:monitored_items"),
        )
        made: list[Any] = []
        if room:
            params.ItemsToCreate = asked[:room]
            try:
                made = list(await create(params))
            finally:
                params.ItemsToCreate = asked
        refused = ua.StatusCode(ua.StatusCodes.BadTooManyMonitoredItems)
        return made + [ua.MonitoredItemCreateResult(StatusCode=refused) for _ in asked[room:]]

    service.create_monitored_items = bounded
