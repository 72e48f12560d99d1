"""A process an instrument (`bench`, `stress`) starts ends with it, however the instrument ends.

`stop_on_terminate` covers SIGTERM and Ctrl-C, where the instrument's own code stops what it
started. SIGKILL (`kill -9`, the OOM killer, a CI runner giving up) runs none of its code, and
neither does an exit between starting a child and keeping hold of it: the gateways, simulated
lines and brokers it started went on running, the simulators holding their ptys, an orphaned
gateway reopening a pty path that the kernel later gave another run's simulated line (whose own
gateway then found the port locked). The kernel does it instead: PR_SET_PDEATHSIG, set in the
child between fork and exec, sends the child SIGTERM when its parent ends.

The "parent" is the thread that started the child: start children from the main thread (where
asyncio.run's loop runs), not from a worker thread (asyncio.to_thread), whose end would stop
them early. And the kernel forgets the setting when the child changes its user (Mosquitto,
started as root, becomes "mosquitto" unless its configuration says `user root`).
"""

from __future__ import annotations

import ctypes
import os
import signal
from collections.abc import Callable

from gateway.libc import process_libc

PR_SET_PDEATHSIG = 1  # <linux/prctl.h>


def die_with_parent() -> Callable[[], None]:
    """A `preexec_fn` for subprocess.Popen: the child gets SIGTERM when this thread ends."""
    parent = os.getpid()
    libc = process_libc()  # loaded here: the child, between fork and exec, only calls it
    if libc is None:
        raise OSError("no libc to set PR_SET_PDEATHSIG with (not Linux)")

    def in_the_child() -> None:
        if libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM, 0, 0, 0) != 0:
            raise OSError(ctypes.get_errno(), "prctl(PR_SET_PDEATHSIG) failed")
        if os.getppid() != parent:
            os._exit(1)  # the parent ended before the setting took effect: never start

    return in_the_child
