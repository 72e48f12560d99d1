"""The local store: nothing a plant must know of is lost to a broker outage or a restart.

- `records`: what is kept (an event with its id and original time; a fault with its snapshot);
- `schema`: the tables as numbered migrations, applied on open; a newer release's file refused;
- `space`: how much of its disk the store may take (max_mb, and a reserve left free);
- `database`: the SQLite file (WAL mode), its bounds, its queries; used only from the store's
  own thread;
- `events`: the `EventStore` the rest of the gateway talks to, on the event loop: `record`
  returns at once; writing, reading and trimming run on the store's one thread; what the disk
  can't take waits in memory and goes to the broker from there. Its reading half is `reads`
  (events, faults, history windows, configuration versions), its forwarding half
  `forwarding` (what the broker doesn't have yet, marked delivered once acknowledged);
- `status`: whether events are kept on disk now, for /health, `healthcheck` and the console;
  the store's counters, for /metrics;
- `modbus_writes`: SCADA writes counted per client, unit id and minute, one event each;
- `outage_buffer` (with its rows, `outage_rows`): running values polled while a connection to
  the broker was away, kept in the same file until that connection delivered them;
- `counters`: numbers that count on across restarts (the Sparkplug edge node's bdSeq).
"""

from gateway.store.events import EventStore
from gateway.store.records import EventType, FaultRecord, NewEvent, StoredEvent

__all__ = ["EventStore", "EventType", "FaultRecord", "NewEvent", "StoredEvent"]
