"""Tighter timer slack for the simulated drives' thread, which answers on a schedule.

Linux lets a sleeping thread wake up to `timer_slack_ns` (50 µs by default) late, to batch wake-ups.
At 115200 baud the inter-frame gap is 1.75 ms and a whole transaction about 8 ms: 50 µs on every
reply is a measurable share of the line. The gateway itself needs none of this: its gap ends on a
timerfd, which has no slack, and nothing else it waits for is timed that finely.
Elsewhere (or if the call is refused) nothing changes: replies only come a little later.
"""

from __future__ import annotations

from gateway.libc import process_libc

PR_SET_TIMERSLACK = 29


def tighten_timer_slack() -> bool:
    """Set the calling thread's timer slack to 1 ns; True if the kernel took it."""
    libc = process_libc()
    if libc is None or not hasattr(libc, "prctl"):
        return False
    return int(libc.prctl(PR_SET_TIMERSLACK, 1, 0, 0, 0)) == 0
