"""The local store: nothing a plant must know of is lost to a broker outage or a restart.

- `records`: what is kept (an event with its id and original time; a fault with its snapshot);
- `database`: the SQLite file (WAL mode), its bounds, its queries; used only from the store's
  own thread;
- `events`: the `EventStore` the rest of the gateway talks to, on the event loop: `record`
  returns at once; writing, reading and trimming run on the store's one thread;
- `modbus_writes`: SCADA writes counted per client, unit id and minute, one event each.
"""

from gateway.store.events import EventStore
from gateway.store.records import EventType, FaultRecord, NewEvent, StoredEvent

__all__ = ["EventStore", "EventType", "FaultRecord", "NewEvent", "StoredEvent"]
