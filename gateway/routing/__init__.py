"""The routing room: the one way to a drive, and the owner of the poll cache.

- `router`: a unit id or a drive's route to its bus; reads through the cache, writes through it,
  polls that fill it; long requests split, parameter writes to their RAM-only twin.
- `cache`: the last polled value of each register, and the rules that keep it from going stale.
"""

from gateway.routing.cache import RegisterCache
from gateway.routing.router import MAX_READ_WORDS, POLL_CLIENT, Route, Router

__all__ = ["MAX_READ_WORDS", "POLL_CLIENT", "RegisterCache", "Route", "Router"]
