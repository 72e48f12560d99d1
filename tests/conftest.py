"""What every test shares: its own state directory, the simulated line most tests run on, a
Mosquitto of its own for the tests that ask for `mosquitto`, and the figures the tests measured
(recovery times, faults survived), shown after the run.

A test records a figure with `record_property("figure:<what>", text)`; they also land in a JUnit
XML report (`--junitxml`) as properties, so CI can keep them.
"""

from __future__ import annotations

import asyncio
import os
import warnings
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any

import pytest

from gateway.config import ENV_STATE_DIRECTORY
from gateway.event_loop import ENV_EVENT_LOOP
from gateway.instruments.simulator import SimulatedLine
from tests.support.mosquitto import mosquitto as mosquitto  # a broker of its own, per test

FIGURE = "figure:"

LINE = {"addresses": (1, 2), "baudrate": 115200, "parity": "E", "wire_time": True}
"""The simulated line a test gets unless it says otherwise: two GD350s at 115200 8E1, the wire's
time emulated. A module says otherwise with `pytestmark = pytest.mark.line(addresses=[1, 2, 3])`,
a test with the same decorator; any `SimulatedLine` argument may be given, and `link="<name>"`
puts a symlink of that name in the test's tmp_path in front of the pty."""


BOTH_LOOPS = (
    "tests/unit/bus/",
    "tests/unit/tcp/",
    "tests/system/test_real_lines.py",
    "tests/system/test_line_faults.py",
    "tests/system/test_direction_control.py",
    "tests/system/test_recovery.py",
    "tests/system/test_serial_server.py",
    "tests/system/test_scheduling.py",
    "tests/system/test_gateway.py",
    "tests/system/test_tcp_front_door.py",
    "tests/system/test_tcp_protection.py",
    "tests/system/test_tcp_security.py",
    "tests/system/test_tcp_slow_clients.py",
)
"""The line, the bus, the TCP server (TLS included) and the port's recovery, tested in-process on
both event loops: uvloop, which the service runs on where it is installed, and asyncio's own,
which it falls back to (a 32-bit ARM box, `INVT_GATEWAY_EVENT_LOOP=asyncio`)."""


def _closing_left_servers(base: type[Any]) -> Callable[[], asyncio.AbstractEventLoop]:
    """uvloop's loops for the tests, which close the servers a test left listening as they
    close, and say so (a warning: an error in this suite). uvloop's own close runs its loop
    until every handle is closed, and a listening server's never is: a test that failed before
    its cleanup stopped a server (its embedded broker, say) held the whole run there for good,
    in `Runner.close`, the loop in epoll_wait."""

    class ClosingLeftServers(base):  # type: ignore[misc]
        def __init__(self) -> None:
            super().__init__()
            self.servers: list[asyncio.AbstractServer] = []

        async def create_server(self, *args: Any, **kwargs: Any) -> asyncio.AbstractServer:
            server: asyncio.AbstractServer = await super().create_server(*args, **kwargs)
            self.servers.append(server)
            return server

        async def create_unix_server(self, *args: Any, **kwargs: Any) -> asyncio.AbstractServer:
            server: asyncio.AbstractServer = await super().create_unix_server(*args, **kwargs)
            self.servers.append(server)
            return server

        def close(self) -> None:
            left = [server for server in self.servers if server.is_serving()]
            for server in left:
                server.close()
            self.servers.clear()
            super().close()
            if left:
                warnings.warn(
                    f"the test left {len(left)} server(s) listening; closed with its loop",
                    ResourceWarning,
                    stacklevel=2,
                )

    return ClosingLeftServers


def pytest_asyncio_loop_factories(
    config: pytest.Config, item: pytest.Item
) -> Mapping[str, Callable[[], asyncio.AbstractEventLoop]]:
    """The loops an async test runs on: the service's (uvloop where installed), and for the
    parts in BOTH_LOOPS asyncio's own as well. `INVT_GATEWAY_EVENT_LOOP=asyncio` runs every test
    on asyncio's loop alone, as it does the gateway processes the tests start."""
    only_asyncio = os.environ.get(ENV_EVENT_LOOP, "").strip().lower() == "asyncio"
    uvloop_factory: Callable[[], asyncio.AbstractEventLoop] | None
    try:
        import uvloop
    except ImportError:
        uvloop_factory = None
    else:
        uvloop_factory = _closing_left_servers(uvloop.Loop)
    factories: dict[str, Callable[[], asyncio.AbstractEventLoop]] = {}
    if uvloop_factory is None or only_asyncio or item.nodeid.startswith(BOTH_LOOPS):
        factories["asyncio"] = asyncio.new_event_loop
    if uvloop_factory is not None and not only_asyncio:
        factories["uvloop"] = uvloop_factory
    return factories


BOTH_LOOPS_RAN = "INVT_CI_BOTH_LOOPS_RAN"
"""Set by `.ci/run`'s second pass, every test on asyncio's loop, for what its first pass ran
already in this very run and the second would only repeat: the async tests of BOTH_LOOPS (run
on asyncio's loop then too), and the unit tests that run no event loop of the service's choosing
(sync ones: pure rooms, budgets, layers, the generated code; none starts a gateway process)."""


def _ran_in_the_first_pass(item: pytest.Item) -> bool:
    is_async = item.get_closest_marker("asyncio") is not None
    if is_async:
        return item.nodeid.startswith(BOTH_LOOPS)
    return item.nodeid.startswith("tests/unit/")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if not os.environ.get(BOTH_LOOPS_RAN):
        return
    ran = [item for item in items if _ran_in_the_first_pass(item)]
    if ran:
        config.hook.pytest_deselected(items=ran)
        left = set(map(id, ran))
        items[:] = [item for item in items if id(item) not in left]


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers", "line(**options): the simulated line's SimulatedLine arguments for this test"
    )


def line_options(request: pytest.FixtureRequest, tmp_path: Path) -> dict[str, Any]:
    options: dict[str, Any] = dict(LINE)
    for marker in reversed(list(request.node.iter_markers("line"))):  # the test's own marker wins
        options.update(marker.kwargs)
    if options.get("link") is not None:
        options["link"] = str(tmp_path / options["link"])
    return options


@pytest.fixture
def line(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[SimulatedLine]:
    """Simulated drives on a real pty, serving while the test runs."""
    with SimulatedLine(**line_options(request, tmp_path)) as simulated:
        yield simulated


@pytest.fixture
def line_link(
    request: pytest.FixtureRequest, tmp_path: Path
) -> Iterator[tuple[SimulatedLine, Path]]:
    """The line behind a stable name (as udev gives a USB adapter), and that name: for the tests
    that unplug and replug it."""
    options = {**line_options(request, tmp_path), "link": str(tmp_path / "usb-FTDI-line1")}
    with SimulatedLine(**options) as simulated:
        yield simulated, Path(options["link"])


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    figures = [
        (name.removeprefix(FIGURE), value)
        for report in terminalreporter.stats.get("passed", [])
        if report.when == "call"
        for name, value in report.user_properties
        if isinstance(name, str) and name.startswith(FIGURE)
    ]
    if figures:
        terminalreporter.section("figures")
        for name, value in figures:
            terminalreporter.write_line(f"{name}: {value}")


@pytest.fixture(autouse=True, scope="session")
def session_state_directory(tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """A store for the gateways that module- and session-scoped fixtures start, which come
    before `own_state_directory` sets each test's: never the machine's /var/lib/invt-gateway
    (a store there, left by another release, refused such a gateway's start)."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv(ENV_STATE_DIRECTORY, str(tmp_path_factory.mktemp("session-state")))
        yield


@pytest.fixture(autouse=True)
def own_state_directory(
    tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Each test its own store (`storage.path` defaults to $STATE_DIRECTORY/events-<gateway_id>.db),
    for the gateways it runs in-process and the ones it starts as subprocesses alike: never the
    machine's /var/lib/invt-gateway, never what another test left."""
    monkeypatch.setenv(ENV_STATE_DIRECTORY, str(tmp_path_factory.mktemp("state")))
