"""Polling: each drive's poll groups read on their intervals, decoded into the drive's state.

- `plan`: which blocks of registers to read from a drive and how often (profile or YAML).
- `drive_state`: what the gateway knows of one drive: raw registers, telemetry, availability.
- `poller`: the feature that runs one polling loop per drive, asking the router to poll.
"""

from gateway.poller.drive_state import DriveEvent, DriveState, EventKind
from gateway.poller.plan import PollBlock, PollSchedule, poll_schedules
from gateway.poller.poller import Poller, PollListener

__all__ = [
    "DriveEvent",
    "DriveState",
    "EventKind",
    "PollBlock",
    "PollListener",
    "PollSchedule",
    "Poller",
    "poll_schedules",
]
