"""One RS-485 line: its queue, its policy and its serial port.

- `line`: the serial port, used from one thread only (blocking I/O with exact timing).
- `queue`: the bounded priority queue with per-client fairness and coalescing of identical reads.
- `health`: which drives are offline, and when to probe them.
- `bus`: the asyncio side that owns all of the above and applies the timeout/retry policy.
"""

from gateway.bus.bus import Bus, BusSettings, BusState, BusStats, DriveStats, RequestDone
from gateway.bus.queue import Priority

__all__ = ["Bus", "BusSettings", "BusState", "BusStats", "DriveStats", "Priority", "RequestDone"]
