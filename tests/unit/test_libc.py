"""libc reached without a child process: a child forked while a serial port is open holds the
port's exclusive lock until it execs, and the simulated drives' thread looking libc up while the
gateway opened its port left the gateway with "Could not exclusively lock port" (a flaky test,
then, in CI)."""

from __future__ import annotations

import json
import subprocess
import sys

# Run in a fresh interpreter: libc is looked up once a process, and an audit hook, once added,
# stays for the rest of the process.
WATCHED = """
import json, sys
spawned = []
def record(event, args):
    if event in ("subprocess.Popen", "os.posix_spawn", "os.fork", "os.exec"):
        spawned.append(f"{event} {args[:2]!r}")
sys.addaudithook(record)
from gateway import timerfd
from gateway.timer_slack import tighten_timer_slack
slack = tighten_timer_slack()
timer = timerfd.DeadlineTimer()
print(json.dumps({"slack": slack, "timerfd": timer.fd >= 0, "spawned": spawned}))
timer.close()
"""


def test_the_timer_slack_and_timerfd_reach_libc_without_starting_a_process() -> None:
    done = subprocess.run(
        [sys.executable, "-c", WATCHED], capture_output=True, text=True, check=True, timeout=60
    )
    said = json.loads(done.stdout)
    assert said["slack"]  # the kernel took it: prctl was found and called
    assert said["timerfd"]
    assert said["spawned"] == []
