"""The C library this process already has loaded, for the few calls Python 3.11 doesn't wrap
(timerfd, prctl's timer slack and parent-death signal).

It is reached through `dlopen(NULL)`, the process's own symbols, never through
`ctypes.util.find_library`: on Linux that runs `ldconfig -p` in a child process, and a child
forked while a serial port is open holds the port's exclusive lock until it execs. The
simulated drives' thread looked its libc up so while the gateway opened the port on the other
end: the gateway found its port locked by nobody it could see, and retried a second later.
"""

from __future__ import annotations

import ctypes
import functools
import sys


@functools.cache
def process_libc() -> ctypes.PyDLL | None:
    """libc's symbols (Linux), or None elsewhere.

    A PyDLL keeps the GIL through a call: every call made through it returns at once (a timerfd
    armed or read, a prctl), and letting the GIL go and taking it back costs some 300
    instructions a call (callgrind), once per transaction on the line timer."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        return ctypes.PyDLL(None, use_errno=True)
    except OSError:
        return None
