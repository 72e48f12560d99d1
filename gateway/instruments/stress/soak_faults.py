"""The soak's faults, one round after another (`Faults`): drives tripped and reset over MQTT,
a drive stalled, the broker killed and started again, the store's disk filled; and the
simulator's control, one command at a time (`SimulatorControl`)."""

from __future__ import annotations

import asyncio
import contextlib
import errno
import os
import subprocess
import time
from collections import Counter
from collections.abc import Awaitable, Callable, Iterator
from pathlib import Path
from typing import Final

from gateway.instruments.bench.processes import SimulatorProcess
from gateway.instruments.stress.checked_load import STEADY, CheckedLoad
from gateway.instruments.stress.processes import Broker
from gateway.instruments.stress.soak_clients import MqttCommands, Outages

ROUND_S: Final = 600.0
"""A round of every fault; a run shorter does one in its time, each fault shorter in
proportion."""
TRIP_S: Final = 5.0
STALL_S: Final = 4.0
BROKER_S: Final = 20.0
FULL_DISK_S: Final = 60.0
SETTLE_S: Final = 1.0
DISK_SIZE: Final = "32m"
TRIP_CODE: Final = 11  # OL1, motor overload


class SimulatorControl:
    """The simulator's control: one command and its answer at a time (the sampler's `stats`
    and a fault's command would otherwise read each other's answers)."""

    def __init__(self, simulator: SimulatorProcess) -> None:
        self._simulator = simulator
        self._turn = asyncio.Lock()

    async def command(self, text: str) -> str:
        async with self._turn:
            return await asyncio.to_thread(self._simulator.command, text)

    async def frames(self) -> int:
        async with self._turn:
            return int((await asyncio.to_thread(self._simulator.stats))["requests"])


class Faults:
    """One round of faults after another until the run's end."""

    def __init__(
        self,
        round_s: float,
        line: SimulatorControl,
        broker: Broker,
        load: CheckedLoad,
        mqtt: MqttCommands,
        outages: Outages,
        store: Path | None,
        done: Counter[str],
    ) -> None:
        self.round_s = round_s
        self.line = line
        self.broker = broker
        self.load = load
        self.mqtt = mqtt
        self.outages = outages
        self.store = store
        self.done = done
        """Faults carried out, by kind."""

    async def rounds(self, started: float, end: float) -> None:
        plan: list[tuple[float, str, Callable[[], Awaitable[None]]]] = [
            (0.10, "drive trip and reset", lambda: self.trip(2)),
            (0.30, "stalled drive", lambda: self.stall(3)),
            (0.50, "MQTT broker", self.restart_broker),
            (0.65, "drive trip and reset", lambda: self.trip(4)),
        ]
        if self.store is not None:
            plan.append((0.80, "full disk", self.fill_disk))
        round_start = started
        while round_start < end:
            for share, what, fault in plan:
                at = round_start + share * self.round_s
                if at >= end:
                    return
                await _sleep_until(at)
                await fault()
                self.done[what] += 1
            round_start += self.round_s

    def _seconds(self, full_s: float) -> float:
        return max(0.5, full_s * self.round_s / ROUND_S)

    async def trip(self, address: int) -> None:
        await self.line.command(f"fault {address} {TRIP_CODE}")
        await asyncio.sleep(self._seconds(TRIP_S))
        answer = await self.mqtt.ask(f"drive{address}/set", {"command": "fault_reset"})
        if answer is None or answer.get("status") != "ok":
            # Counted by the dashboard already; the drive must not stay tripped for the rounds
            # after (its reset is what failed, not the plant).
            await self.line.command(f"clear {address}")

    async def stall(self, address: int) -> None:
        self.load.phase = "stalled drive"
        self.outages.begin("stalled drive")
        seconds = self._seconds(STALL_S)
        await self.line.command(f"stall {address} {seconds:.2f}")
        await asyncio.sleep(seconds + SETTLE_S)
        self.outages.end("stalled drive")
        self.load.phase = STEADY

    async def restart_broker(self) -> None:
        self.outages.begin("MQTT broker")
        await asyncio.to_thread(self.broker.kill)
        await asyncio.sleep(self._seconds(BROKER_S))
        self.broker.start()
        await asyncio.to_thread(self.broker.wait_listening)
        self.outages.end("MQTT broker")

    async def fill_disk(self) -> None:
        assert self.store is not None
        filler = self.store / "filler"
        await asyncio.to_thread(_fill, filler)
        try:
            await asyncio.sleep(self._seconds(FULL_DISK_S))
        finally:
            filler.unlink(missing_ok=True)


def _fill(path: Path) -> None:
    """Write `path` until its disk is full, as a runaway log would."""
    chunk = 64 * 1024
    with path.open("wb", buffering=0) as out:
        while chunk:
            try:
                out.write(b"\0" * chunk)
            except OSError as exc:
                if exc.errno != errno.ENOSPC:
                    raise
                chunk //= 2


@contextlib.contextmanager
def store_disk(folder: Path, left_out: dict[str, str]) -> Iterator[Path | None]:
    """`folder` a tmpfs of its own for the store (a disk the soak may fill), or a plain folder
    (yielding None) when this process may not mount one."""
    folder.mkdir()
    if os.geteuid() != 0:
        left_out["full disk"] = "mounting a small file system needs root"
        yield None
        return
    mount = ["mount", "-t", "tmpfs", "-o", f"size={DISK_SIZE}", "tmpfs", str(folder)]
    mounted = subprocess.run(mount, capture_output=True, text=True, check=False)
    if mounted.returncode != 0:
        left_out["full disk"] = f"mount failed: {mounted.stderr.strip()[:100]}"
        yield None
        return
    try:
        yield folder
    finally:
        subprocess.run(["umount", "--lazy", str(folder)], check=False)


async def _sleep_until(moment: float) -> None:
    await asyncio.sleep(max(0.0, moment - time.monotonic()))
