"""The event loop the service runs on: uvloop where it is installed, asyncio's own otherwise.

Most of what a bus transaction costs the gateway is the event loop's own work: three passes of it
per transaction (a client's request, the drive's reply, the end of the gap), the system calls and
the handles behind each. uvloop does that work in C: `bench --instructions` counts 19 % fewer
instructions per transaction on it (327,268 -> 263,916 on 2026-11-23, counted in turn), and
with 4 lines of fast drives the gateway needs a quarter less of a core.

The line's timing doesn't depend on the loop: uvloop's timers have millisecond resolution, but the
gap before each request and the response timeout are kept by the line's own timerfd, and every
finer wait re-checks the clock when it wakes. uvloop ships as a wheel for Linux on x86-64 and
ARM64 only; elsewhere (a 32-bit Raspberry Pi OS) the package installs without it and the gateway
runs on asyncio's loop, unchanged but for the CPU it takes.

`INVT_GATEWAY_EVENT_LOOP` picks: `auto` (the default: uvloop if it imports), `uvloop` (refuse to
start without it) or `asyncio` (asyncio's own loop, say to rule the loop out of a fault).
"""

from __future__ import annotations

import asyncio
import importlib
import os
import platform
from collections.abc import Callable, Coroutine
from dataclasses import dataclass
from typing import Any, TypeVar

from gateway.errors import ConfigError

ENV_EVENT_LOOP = "INVT_GATEWAY_EVENT_LOOP"
CHOICES = ("auto", "uvloop", "asyncio")
T = TypeVar("T")


@dataclass(frozen=True, slots=True)
class EventLoopChoice:
    name: str
    """"uvloop" or "asyncio": what the service runs on."""
    version: str
    """uvloop's version, or the Python version for asyncio's own loop."""
    factory: Callable[[], asyncio.AbstractEventLoop] | None
    """None: asyncio's default loop."""
    why: str = ""
    """Why asyncio's loop when uvloop was possible ("uvloop not installed", "asked for")."""

    def describe(self) -> str:
        text = f"{self.name} {self.version}"
        return f"{text} ({self.why})" if self.why else text


def choose_event_loop(wanted: str | None = None) -> EventLoopChoice:
    """The loop `wanted` names (default: the environment's `INVT_GATEWAY_EVENT_LOOP`, else
    `auto`). Raises ConfigError for a name it doesn't know or for uvloop asked for but missing."""
    if wanted is None:
        wanted = os.environ.get(ENV_EVENT_LOOP, "").strip().lower() or "auto"
    if wanted not in CHOICES:
        raise ConfigError([(ENV_EVENT_LOOP, f"{wanted!r} is not one of {', '.join(CHOICES)}")])
    python = platform.python_version()
    if wanted == "asyncio":
        return EventLoopChoice("asyncio", python, None, f"{ENV_EVENT_LOOP}=asyncio")
    try:
        uvloop = importlib.import_module("uvloop")
    except ImportError as exc:
        if wanted == "uvloop":
            reason = f"uvloop asked for, but it doesn't import ({exc})"
            raise ConfigError([(ENV_EVENT_LOOP, reason)]) from exc
        return EventLoopChoice("asyncio", python, None, "uvloop not installed")
    factory: Callable[[], asyncio.AbstractEventLoop] = uvloop.new_event_loop
    return EventLoopChoice("uvloop", str(getattr(uvloop, "__version__", "?")), factory)


def running_loop_name() -> str:
    """ "uvloop" or "asyncio": the loop this code runs on (for the build info metric), a
    subclass of uvloop's too (the tests' loops are)."""
    kinds = type(asyncio.get_running_loop()).__mro__
    return "uvloop" if any(kind.__module__.startswith("uvloop") for kind in kinds) else "asyncio"


def run(main: Coroutine[Any, Any, T], choice: EventLoopChoice) -> T:
    """`asyncio.run(main)` on the chosen loop."""
    with asyncio.Runner(loop_factory=choice.factory) as runner:
        return runner.run(main)
