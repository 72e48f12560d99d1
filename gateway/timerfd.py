"""Linux's timerfd through libc: a file descriptor that becomes readable at a nanosecond deadline.

Python 3.11 has no `os.timerfd_create` (3.13 has). A descriptor that a selector watches like any
other gives a wait to the nanosecond where the selectors' own timeouts are whole milliseconds
(epoll) or cost a scan of every descriptor (select). Two users: the gateway's line timer (the
inter-frame gap, on the event loop) and the simulated drives' line server (replies due on the
microsecond, on a thread).
"""

from __future__ import annotations

import ctypes
import functools
import math
import os
from collections.abc import Callable

from gateway.libc import process_libc

_ceil = math.ceil
"""A module global: `math.ceil` is an attribute read more, once per transaction."""

CLOCK_MONOTONIC = 1
"""The clock behind `time.monotonic()` on Linux: deadlines are passed through unchanged."""
TFD_NONBLOCK = os.O_NONBLOCK
TFD_CLOEXEC = os.O_CLOEXEC
TFD_TIMER_ABSTIME = 1

Itimerspec = ctypes.c_long * 4
"""struct itimerspec as four longs: it_interval (seconds, nanoseconds), then it_value. A flat
array rather than nested Structures: `spec.it_value.tv_sec = ...` builds a view object of the
inner struct on every access, and a line's timer is armed once per transaction."""
VALUE_SECONDS = 2
VALUE_NANOSECONDS = 3


@functools.cache
def libc() -> ctypes.PyDLL | None:
    """libc where it has timerfd (Linux), else None."""
    found = process_libc()
    if found is None or not hasattr(found, "timerfd_create"):
        return None
    return found


def create() -> int:
    """A new non-blocking timerfd on the monotonic clock; -1 where there is none."""
    found = libc()
    if found is None:
        return -1
    return int(found.timerfd_create(CLOCK_MONOTONIC, TFD_NONBLOCK | TFD_CLOEXEC))


class DeadlineTimer:
    """One timerfd armed at an absolute `time.monotonic()` deadline, or disarmed.

    Arming again replaces the deadline and clears the expiry count, so a waiter that arms before
    each wait never has to read the descriptor; it is readable once the deadline armed last has
    passed, until armed again or disarmed. A caller that arms once per transaction may write
    `arm_at` out: `spec[VALUE_SECONDS]`, `spec[VALUE_NANOSECONDS]`, then
    `settime(fd, TFD_TIMER_ABSTIME, spec, None)` (0 when done)."""

    __slots__ = ("fd", "settime", "spec")

    def __init__(self) -> None:
        self.fd = create()
        """-1 where the system has no timerfd: `arm_at` and `disarm` return False then."""
        found = libc()
        self.settime: Callable[..., int] | None = None if found is None else found.timerfd_settime
        """libc's, looked up once: a CDLL's attributes go through its `__getattr__` hook on
        every access."""
        self.spec = Itimerspec()

    def arm_at(self, deadline: float) -> bool:
        """Readable at `deadline`, rounded up to the nanosecond: never early."""
        at_ns = _ceil(deadline * 1e9)
        if at_ns < 1:  # an all-zero it_value would disarm the timer instead of firing it
            at_ns = 1
        seconds, nanoseconds = divmod(at_ns, 1_000_000_000)
        return self._write(seconds, nanoseconds, TFD_TIMER_ABSTIME)

    def disarm(self) -> bool:
        """Never readable until armed again (the expiry count cleared too)."""
        return self._write(0, 0, 0)

    def close(self) -> None:
        fd, self.fd = self.fd, -1
        if fd >= 0:
            os.close(fd)

    def _write(self, seconds: int, nanoseconds: int, flags: int) -> bool:
        if self.fd < 0 or self.settime is None:
            return False
        # A callable attribute: read, then called (a method call's lookup of it is generic on
        # Python 3.11, a plain read is specialised).
        spec, settime = self.spec, self.settime
        spec[VALUE_SECONDS] = seconds
        spec[VALUE_NANOSECONDS] = nanoseconds
        return int(settime(self.fd, flags, spec, None)) == 0  # an array: its address
