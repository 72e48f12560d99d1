"""What to change when a line's hardware shows itself in the replies: words for the log and `scan`.

The line notices two effects of common hardware (`gateway.bus.receiver`) and copes with both; these
say, once, what would make it cleaner, in terms a technician can act on.
"""

from __future__ import annotations

import os
from pathlib import Path

USB_SERIAL_SYSFS = Path("/sys/bus/usb-serial/devices")
"""Where Linux's usb-serial drivers show their devices; FTDI's have a `latency_timer` there."""


def latency_timer_path(port: str) -> Path | None:
    """The FTDI latency timer of the adapter behind `port` (a path or a by-id link), if any."""
    if "://" in port:
        return None
    device = os.path.basename(os.path.realpath(port))
    path = USB_SERIAL_SYSFS / device / "latency_timer"
    return path if path.exists() else None


def burst_hint(where: str, port: str, silence_s: float) -> str:
    """The log line for replies that arrive in bursts."""
    text = (
        f"{where}: replies arrive in bursts (a silence of {silence_s * 1000:.0f} ms inside one): "
        "the adapter hands received bytes over in batches. Replies are still read whole, by "
        "their length; each transaction takes longer by about that much."
    )
    if "://" in port:
        return text + (
            " A serial device server packs bytes into TCP segments: set its packing or "
            "'force transmit' interval to the smallest it allows."
        )
    timer = latency_timer_path(port)
    if timer is not None:
        try:
            now = f" (now {timer.read_text().strip()} ms)"
        except OSError:
            now = ""
        return text + (
            f" This is an FTDI adapter: its latency timer{now} can be set to 1 ms with "
            f"`echo 1 > {timer}` (a udev rule makes it stick)."
        )
    return text + (
        " For an FTDI adapter, /sys/bus/usb-serial/devices/<ttyUSBn>/latency_timer (16 ms by "
        "default) can be set to 1."
    )


def echo_hint(where: str) -> str:
    """The log line for an adapter that echoes though the config says it doesn't."""
    return (
        f"{where}: this adapter echoes what the gateway sends (a 2-wire adapter without echo "
        "suppression): set `echo: true` for this bus. Meanwhile each reply is found after the "
        "echo, and the echo is never taken for a reply."
    )
