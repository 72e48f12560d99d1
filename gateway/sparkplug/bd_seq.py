"""An edge node's `bdSeq`: one more at every CONNECT (its will's NDEATH carries it, the NBIRTH
that follows repeats it), across restarts too, so it is kept in the store and committed before
the CONNECT (the edge node's module says why the specification wants it so). A redundant box
taking the node over counts on from the other box's last birth (`follow_on`)."""

from __future__ import annotations

import logging

from gateway.errors import StoreError
from gateway.sparkplug import payload
from gateway.store import EventStore

log = logging.getLogger(__name__)


class BirthDeathSequence:
    """The node's bdSeq: `value` the last CONNECT's (-1 before the first)."""

    def __init__(self, events: EventStore, group_id: str, edge_node_id: str) -> None:
        self._events = events
        self._number = payload.SequenceNumber()
        # The counter in the store: an edge node's own (another group or node id: from 0).
        self._key = f"sparkplug bdSeq {group_id}/{edge_node_id}"
        self._unkept = False  # the store could not keep it: counted on in memory
        self._after: int | None = None
        """A redundant box taking over: the bdSeq the other box's node was last born with."""

    @property
    def value(self) -> int:
        return self._number.value

    @value.setter
    def value(self, value: int) -> None:
        self._number.value = value

    def follow_on(self, bd_seq: int) -> None:
        """A redundant box takes the node over from the other box, whose node was last born
        with `bd_seq`: this box's next CONNECT counts on from it, so the node's bdSeq goes up
        by one at every CONNECT whichever box makes it, and the old box's NDEATH (its will,
        published late when its network went) never carries the new birth's bdSeq."""
        self._after = bd_seq

    async def next(self) -> int:
        """The next CONNECT's, kept in the store before it is returned (in memory if the store
        can't keep it, said once)."""
        after, self._after = self._after, None
        try:
            self.value = await self._events.count_on(self._key, payload.SEQUENCE_MODULO, after)
            self._unkept = False
        except StoreError as exc:
            if not self._unkept:
                log.warning(
                    "Sparkplug: the store cannot keep the bdSeq (%s); counting on in memory, "
                    "a restart starts again at 0",
                    exc,
                )
            self._unkept = True
            if after is not None:
                self.value = after
            self._number.next()
        return self.value
