"""One RS-485 line: its queue, its policy and its serial port.

- `line`: the inter-frame gap and each attempt's start, on the event loop, with its parts:
  `port` (a tty the loop watches, or a pyserial URL), `receiver` (the bytes heard and the reply
  among them), `rts` (RTS around each request), `reply_reader` (what the caller reads itself).
- `line_timer`: exact wake-ups for the inter-frame gap (a timerfd the loop watches).
- `wakeup`: how a waiting coroutine of the bus or the line is woken, or times out.
- `queue`: the bounded priority queue with per-client fairness and coalescing of identical reads.
- `health`: which drives are offline, and when to probe them.
- `bus`: the coroutine that owns all of the above and applies the timeout/retry policy.
"""

from gateway.bus.bus import Bus, BusSettings, BusState, BusStats, DriveStats, RequestDone
from gateway.bus.queue import Priority

__all__ = ["Bus", "BusSettings", "BusState", "BusStats", "DriveStats", "Priority", "RequestDone"]
