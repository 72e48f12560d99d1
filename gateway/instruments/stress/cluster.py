"""`stress --cluster`: gateways riding a three-node NATS cluster's failures (issue 33's proof).

Three nats-server nodes (cluster routes, JetStream, MQTT, `stream_replicas: 3`) on free loopback
ports; gateways as subprocesses, each on its own simulated line of 16 drives, each listing every
node in `mqtt.servers` (each a different first); a dashboard with a persistent QoS 1 session on
every gateway's events and state; an operator sending set-points all along, each a frequency no
other command has. Drive 1 of every line trips and resets all along: a steady stream of events.

    0 %             everything up; every drive's retained state read through every node
    10, 35, 60 %    the node gateway 1, 2, 3 is connected to is SIGKILLed: the time until each
                    gateway that used it says "online" through another node; the retained
                    states read through the two live nodes; the node started again, read again
    85 %            gateway 2 is SIGKILLed and started again: its time back; read again
    100 %           every event id the gateways stored looked for at the dashboard; every
                    command event counted by its frequency

Each retained read waits until every live node takes an MQTT client and the nodes carry retained
messages between them again (a probe published through each is read through every other: NATS's
own recovery after a node's death, its time printed beside the read), puts a new fault code on
every drive of every line, and measures from there: a drive's state is read fresh (a new
client, its retained messages) through each live node until every drive shows its new code, or
`RETAINED_WITHIN_S` has passed.
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import json
import sqlite3
import tempfile
import time
import uuid
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

from gateway.instruments.bench.processes import SimulatorProcess, free_port, stop_process
from gateway.instruments.nats_cluster import NatsNode, nats_cluster
from gateway.instruments.stress.cluster_clients import (
    Dashboard,
    Operator,
    SetPoint,
    StateWatch,
    quiet_lost_connections,
    read_retained,
    wait_carrying_retained,
)
from gateway.instruments.stress.processes import Gateway, launch_simulator, simulator_started

RETAINED_WITHIN_S: Final = 5.0
CLUSTER_WAIT_S: Final = 30.0
"""How long a retained read's change waits for the live nodes to share retained messages."""
RESUME_LIMIT_S: Final = 30.0
"""From a node's (or a gateway's) SIGKILL to the gateway's "online": what is "not back"."""
DELIVERY_WAIT_S: Final = 20.0
"""At the end, how long events still under way may take to reach the dashboard."""
NODE_KILL_AT: Final = (0.10, 0.35, 0.60)
GATEWAY_KILL_AT: Final = 0.85
KILLED_GATEWAY: Final = 1
"""Which gateway is SIGKILLed and restarted (the second: its node died in the run too)."""
FAULT_CODES: Final = (11, 13, 14)
"""Put on every drive, one after another, by the retained reads."""
TOGGLE_CODE: Final = 12
"""Drive 1 trips with this and is reset, all along."""
TOGGLE_S: Final = 0.5
STATE_POLL: Final = [{"name": "state", "start": 0x2100, "count": 3, "interval_ms": 1000}]
"""The state words only (what a fault changes), each drive every second: 16 requests a second
on each line, so a change is in the retained state well inside `RETAINED_WITHIN_S`."""
FIRST_FREQUENCY_HZ: Final = 5.0
FREQUENCY_STEP_HZ: Final = 0.01
"""Each set-point a step above the last: a command's frequency names it (the set-point's
resolution is 0.01 Hz)."""


@dataclass(frozen=True, slots=True)
class ClusterSettings:
    duration_s: float = 120.0
    gateways: int = 3
    drives: int = 16
    command_interval_s: float = 0.5


@dataclass(frozen=True, slots=True)
class Resume:
    gateway: str
    cause: str
    seconds: float | None
    """From the SIGKILL to its "online", seen first through any live node (`StateWatch`);
    None: not within RESUME_LIMIT_S."""
    dashboard_s: float | None
    """... and at the dashboard's persistent QoS 1 session; None: not before the gateway's
    next kill or the run's end (NATS 2.9 may hold a session's deliveries until a dead node
    is back)."""
    server: str | None
    """The node it came back through (its name, n0..n2)."""


@dataclass(frozen=True, slots=True)
class RetainedRead:
    moment: str
    node: str
    seconds: float | None
    """From the change to a read showing every drive's new state; None: not within 5 s."""
    stale: tuple[str, ...] = ()
    """The drives' topics not showing it at the last read."""
    cluster_wait_s: float | None = 0.0
    """Before the change: until the live nodes carried retained messages between them again;
    None: not within `CLUSTER_WAIT_S` (the change was made anyway)."""


@dataclass(frozen=True, slots=True)
class Delivery:
    gateway: str
    stored: int
    received: int
    """Every event message the dashboard got from it, duplicates included."""
    distinct: int
    missing: tuple[int, ...]


@dataclass(frozen=True, slots=True)
class CommandCount:
    sent: int
    """Acknowledged by a node (QoS 1)."""
    unacknowledged: int
    ran: int
    """Distinct set-points with a `command` event in a gateway's store."""
    ran_twice: tuple[float, ...]
    """Frequencies with more than one `command` event: must be none."""
    unsent_ran: int
    """Ran, though the node died before acknowledging it (at most once allows it)."""


@dataclass
class ClusterResult:
    settings: ClusterSettings
    elapsed_s: float = 0.0
    node_kills: int = 0
    gateway_kills: int = 0
    resumes: list[Resume] = field(default_factory=list)
    retained: list[RetainedRead] = field(default_factory=list)
    deliveries: list[Delivery] = field(default_factory=list)
    commands: CommandCount = CommandCount(0, 0, 0, (), 0)
    dashboard_connections: int = 0
    logs: dict[str, str] = field(default_factory=dict)
    """Last lines of each gateway's log, for a failed run."""


class Line:
    """One gateway on its simulated line, and what the run needs of them."""

    def __init__(self, index: int, site: str, nodes: list[NatsNode], directory: Path) -> None:
        self.name = f"g{index + 1}"
        self.base = f"{site}/{self.name}"
        self.folder = directory / self.name
        self.folder.mkdir()
        self.link = self.folder / "ttyRS485"
        self.store = self.folder / "events.db"
        # Each gateway lists every node, a different one first: the cluster's load spread.
        self.servers = [nodes[(index + n) % len(nodes)].address for n in range(len(nodes))]
        self.simulator: SimulatorProcess | None = None
        self.gateway: Gateway | None = None

    def config(self, drives: int) -> dict[str, Any]:
        return {
            "gateway_id": self.name,
            "modbus_tcp": {"host": "127.0.0.1", "port": free_port()},
            "buses": [{"name": "line1", "port": str(self.link), "baudrate": 115200, "parity": "N"}],
            "drives": [
                {"name": f"drive{n}", "bus": "line1", "address": n, "poll": STATE_POLL}
                for n in range(1, drives + 1)
            ],
            "mqtt": {
                "servers": self.servers,
                "base_topic": self.base,
                "homeassistant_discovery": False,
                "reconnect_max_s": 1.0,
                "publish_interval_s": 0.5,
                "keepalive_s": 5,
                # What the Operations page advises on a NATS cluster: a QoS 1 message NATS
                # can't store yet (a stream electing its leader) closes its connection.
                "publish_qos": 0,
                "own_events_connection": True,
            },
            "storage": {"path": str(self.store)},
            "logging": {"level": "warning"},
        }

    def simulator_arguments(self, drives: int) -> list[str]:
        arguments = ["--link", str(self.link), "--baud", "115200", "--parity", "N"]
        # Several lines on one machine: none spins to time its replies (`simulate --help`).
        arguments += ["--wake-early-us", "0"]
        for address in range(1, drives + 1):
            arguments += ["--address", str(address)]
        return arguments

    def drive_topics(self, drives: int) -> list[str]:
        return [f"{self.base}/drive{n}" for n in range(1, drives + 1)]

    def stored(self) -> list[tuple[int, str, str]]:
        """(id, type, data) of every event in the gateway's store (read-only: it may run)."""
        uri = f"file:{self.store}?mode=ro"
        with contextlib.closing(sqlite3.connect(uri, uri=True)) as db:
            return list(db.execute("SELECT id, type, data FROM events ORDER BY id"))


async def run_cluster_stress(
    settings: ClusterSettings, progress: Callable[[str], None] = lambda _: None
) -> ClusterResult:
    """RuntimeError when the cluster, a line or a gateway does not start."""
    result = ClusterResult(settings)
    quiet_lost_connections(asyncio.get_running_loop())
    site = f"invt-cluster-{uuid.uuid4().hex[:8]}"
    with (
        tempfile.TemporaryDirectory(prefix="invt-stress-cluster-") as folder,
        nats_cluster(Path(folder)) as nodes,
    ):
        lines = [Line(index, site, nodes, Path(folder)) for index in range(settings.gateways)]
        # Started here, on the loop's thread (`die_with_parent`), and held at once.
        launched = [launch_simulator(line.simulator_arguments(settings.drives)) for line in lines]
        dashboard = Dashboard(nodes, site)
        watch = StateWatch(nodes, site)
        watching = [
            asyncio.create_task(dashboard.run(), name="stress:dashboard"),
            asyncio.create_task(watch.run(), name="stress:watch"),
        ]
        try:
            for line, process in zip(lines, launched, strict=True):
                line.simulator = await asyncio.to_thread(simulator_started, process)
            for node in nodes:
                await node.wait_serving()
            progress(f"cluster of {len(nodes)} nodes serving; starting {len(lines)} gateways")
            for line in lines:
                line.gateway = Gateway(line.config(settings.drives), line.folder)
                line.gateway.start()
            for line in lines:
                assert line.gateway is not None
                await asyncio.to_thread(line.gateway.wait_listening)
            for line in lines:
                if await _online_after(dashboard, line, 0.0) is None:
                    raise RuntimeError(f"gateway {line.name} never came online on the cluster")
            await Run(settings, nodes, lines, dashboard, watch, result, progress).run()
        finally:
            for task in watching:
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await task
            for line in lines:
                if line.gateway is not None:
                    result.logs[line.name] = line.gateway.log_tail()
                    await asyncio.to_thread(line.gateway.stop)
            for process in launched:
                await asyncio.to_thread(stop_process, process)
        result.dashboard_connections = dashboard.connections
    return result


async def _online_after(
    dashboard: Dashboard, line: Line, moment: float
) -> tuple[float, str] | None:
    """(seconds from `moment`, through which node) of the gateway's next "online", or None."""
    deadline = time.monotonic() + RESUME_LIMIT_S
    while time.monotonic() < deadline:
        online = dashboard.online_after(line.base, moment)
        if online is not None:
            return online.at - moment, str(online.data.get("server"))
        await asyncio.sleep(0.02)
    return None


class Run:
    def __init__(
        self,
        settings: ClusterSettings,
        nodes: list[NatsNode],
        lines: list[Line],
        dashboard: Dashboard,
        watch: StateWatch,
        result: ClusterResult,
        progress: Callable[[str], None],
    ) -> None:
        self.settings = settings
        self.nodes = nodes
        self.lines = lines
        self.dashboard = dashboard
        self.watch = watch
        self.result = result
        self.progress = progress
        self.operator = Operator(nodes)
        self.line_lock = asyncio.Lock()
        """Held while the simulators are talked to: the toggling and a read's changes."""
        self.reads = 0
        self._killed: list[tuple[Line, float, int, str | None]] = []
        """(gateway, when killed, its `Resume`'s index, the dead node's address) of each kill."""

    async def run(self) -> None:
        started = time.monotonic()
        duration = self.settings.duration_s
        stop = asyncio.Event()
        # Not a TaskGroup: a step's RuntimeError comes out as itself, for the command to print.
        tasks = [
            asyncio.create_task(self._toggle(stop), name="stress:toggle"),
            asyncio.create_task(self._command(stop), name="stress:operator"),
        ]
        try:
            await self._read_retained("all nodes up")
            for index, at in enumerate(NODE_KILL_AT[: len(self.lines)]):
                await _sleep_until(started + at * duration)
                await self._kill_node_of(self.lines[index])
            await _sleep_until(started + GATEWAY_KILL_AT * duration)
            await self._kill_gateway(self.lines[KILLED_GATEWAY % len(self.lines)])
            await _sleep_until(started + duration)
        finally:
            stop.set()
            ended = await asyncio.gather(*tasks, return_exceptions=True)
        failed = [each for each in ended if isinstance(each, Exception)]
        if failed:
            raise RuntimeError(f"the drives' faults or the set-points stopped: {failed[0]!r}")
        await self.operator.close()
        self.result.elapsed_s = time.monotonic() - started
        self.progress("run over; waiting for events still under way")
        await self._count_deliveries()
        self._count_commands()
        self._dashboard_times()

    def _server_of(self, line: Line) -> str | None:
        return self.watch.server_of(line.base) or self.dashboard.server_of(line.base)

    async def _kill_node_of(self, line: Line) -> None:
        server = self._server_of(line)
        node = next((n for n in self.nodes if n.address == server), None)
        if node is None:
            raise RuntimeError(f"gateway {line.name} says it is on {server!r}, not a node of ours")
        await self.dashboard.move_off(node)
        on_it = [each for each in self.lines if self._server_of(each) == server]
        killed = time.monotonic()
        node.kill()
        self.result.node_kills += 1
        self.progress(f"node {node.name} SIGKILLed ({', '.join(e.name for e in on_it)} on it)")
        cause = f"its node {node.name} SIGKILLed"
        await asyncio.gather(*(self._resumed(each, killed, cause, server) for each in on_it))
        await self._read_retained(f"{node.name} down")
        node.start()
        await asyncio.to_thread(node.wait_listening)
        await node.wait_serving()
        self.progress(f"node {node.name} back")
        await self._read_retained(f"{node.name} back")

    async def _kill_gateway(self, line: Line) -> None:
        assert line.gateway is not None
        killed = time.monotonic()
        await asyncio.to_thread(line.gateway.kill)
        line.gateway.start()
        self.result.gateway_kills += 1
        self.progress(f"gateway {line.name} SIGKILLed and started again")
        await self._resumed(line, killed, "SIGKILLed and restarted")
        await self._read_retained(f"gateway {line.name} restarted")

    async def _resumed(
        self, line: Line, killed: float, cause: str, dead: str | None = None
    ) -> None:
        """`dead`: the address of the node that died, if one did."""
        deadline = killed + RESUME_LIMIT_S
        while (back := self.watch.online_after(line.base, killed)) is None:
            if time.monotonic() > deadline:
                break
            await asyncio.sleep(0.02)
        seconds, server = (None, None) if back is None else (back[0] - killed, back[1])
        server = next((node.name for node in self.nodes if node.address == server), server)
        self._killed.append((line, killed, len(self.result.resumes), dead))
        self.result.resumes.append(Resume(line.name, cause, seconds, None, server))
        if seconds is None:
            self.progress(f"{line.name}: NOT back within {RESUME_LIMIT_S:.0f} s ({cause})")
        else:
            self.progress(f"{line.name}: online through {server} {seconds:.2f} s after {cause}")

    def _dashboard_times(self) -> None:
        """When the dashboard's session got each "online": before the gateway's next kill."""
        for line, killed, index, dead in self._killed:
            later = [at for each, at, _, _ in self._killed if each is line and at > killed]
            online = self.dashboard.online_after(line.base, killed, not_via=dead)
            if online is not None and (not later or online.at < min(later)):
                resume = self.result.resumes[index]
                self.result.resumes[index] = dataclasses.replace(
                    resume, dashboard_s=online.at - killed
                )

    async def _read_retained(self, moment: str) -> None:
        """A new fault code on every drive, then its retained state through every live node."""
        code = FAULT_CODES[self.reads % len(FAULT_CODES)]
        self.reads += 1
        drives = self.settings.drives
        live = [node for node in self.nodes if node.running]
        # The change is made once every live node takes a client again: right after a node's
        # death the others may refuse any for seconds while they elect leaders (what the
        # resume times measure); what is timed here is a change reaching every node.
        await asyncio.gather(*(node.wait_serving() for node in live))
        cluster_wait = await wait_carrying_retained(live, self.dashboard.site, CLUSTER_WAIT_S)
        async with self.line_lock:
            for line in self.lines:
                assert line.simulator is not None
                for address in range(1, drives + 1):
                    await asyncio.to_thread(line.simulator.command, f"fault {address} {code}")
            changed = time.monotonic()
            topics = {topic for line in self.lines for topic in line.drive_topics(drives)}
            reads = await asyncio.gather(
                *(self._read_through(node, topics, code, changed, moment) for node in live)
            )
        self.result.retained.extend(
            dataclasses.replace(read, cluster_wait_s=cluster_wait) for read in reads
        )
        slowest = max((r.seconds for r in reads if r.seconds is not None), default=0.0)
        late = [r.node for r in reads if r.seconds is None]
        self.progress(
            f"retained ({moment}): {len(topics)} drives through {len(live)} nodes, "
            + (f"NOT within 5 s through {', '.join(late)}" if late else f"{slowest:.2f} s")
            + (
                f" (the nodes shared retained messages after {cluster_wait:.2f} s)"
                if cluster_wait is not None
                else f" (the nodes did NOT share retained messages within {CLUSTER_WAIT_S:g} s)"
            )
        )

    async def _read_through(
        self, node: NatsNode, topics: set[str], code: int, changed: float, moment: str
    ) -> RetainedRead:
        stale: tuple[str, ...] = tuple(sorted(topics))
        while time.monotonic() - changed < RETAINED_WITHIN_S:
            found = await read_retained(node, topics, self.dashboard.site)
            stale = tuple(sorted(t for t in topics if not _shows(found.get(t), code)))
            seconds = time.monotonic() - changed
            if not stale and seconds <= RETAINED_WITHIN_S:
                return RetainedRead(moment, node.name, seconds)
            await asyncio.sleep(0.1)
        return RetainedRead(moment, node.name, None, stale)

    async def _toggle(self, stop: asyncio.Event) -> None:
        tripped = False
        while not stop.is_set():
            async with self.line_lock:
                tripped = not tripped
                command = f"fault 1 {TOGGLE_CODE}" if tripped else "clear 1"
                for line in self.lines:
                    assert line.simulator is not None
                    await asyncio.to_thread(line.simulator.command, command)
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(stop.wait(), TOGGLE_S)

    async def _command(self, stop: asyncio.Event) -> None:
        count = 0
        drives = self.settings.drives
        while not stop.is_set():
            line = self.lines[count % len(self.lines)]
            drive = 2 + (count // len(self.lines)) % (drives - 1) if drives > 1 else 1
            frequency = round(FIRST_FREQUENCY_HZ + count * FREQUENCY_STEP_HZ, 2)
            await self.operator.send(SetPoint(line.base, f"drive{drive}", frequency))
            count += 1
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(stop.wait(), self.settings.command_interval_s)

    async def _count_deliveries(self) -> None:
        deadline = time.monotonic() + DELIVERY_WAIT_S
        while True:
            missing = {
                line.name: {row[0] for row in line.stored()}
                - set(self.dashboard.event_ids(line.base))
                for line in self.lines
            }
            if not any(missing.values()) or time.monotonic() > deadline:
                break
            await asyncio.sleep(0.2)
        for line in self.lines:
            received = self.dashboard.event_ids(line.base)
            self.result.deliveries.append(
                Delivery(
                    line.name,
                    len(line.stored()),
                    len(received),
                    len(set(received)),
                    tuple(sorted(missing[line.name])),
                )
            )

    def _count_commands(self) -> None:
        ran: Counter[float] = Counter()
        for line in self.lines:
            for _, kind, data in line.stored():
                if kind == "command":
                    ran[float(json.loads(data).get("frequency_hz", -1))] += 1
        sent = {point.frequency_hz for point in self.operator.sent}
        self.result.commands = CommandCount(
            sent=len(self.operator.sent),
            unacknowledged=self.operator.failed,
            ran=len(ran),
            ran_twice=tuple(sorted(f for f, n in ran.items() if n > 1)),
            unsent_ran=len(set(ran) - sent),
        )


def _shows(state: Any, code: int) -> bool:
    return isinstance(state, dict) and state.get("fault_code") == code


async def _sleep_until(moment: float) -> None:
    await asyncio.sleep(max(0.0, moment - time.monotonic()))
