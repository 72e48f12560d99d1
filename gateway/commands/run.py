"""`invt-gateway run --config FILE`: the service."""

from __future__ import annotations

import argparse
import asyncio
import logging
import signal
import sys
from collections.abc import Callable, Coroutine, Mapping
from typing import Any

from gateway import ENGINE_ROOM
from gateway.app import Application
from gateway.collector import settle_startup_objects
from gateway.commands.config_path import DEFAULT_CONFIG as DEFAULT_CONFIG
from gateway.config import GatewayConfig, load_config
from gateway.config.startup import startup_problems
from gateway.control import RELOAD, ROLE, ControlServer
from gateway.errors import (
    BrokerShared,
    BusFailed,
    CannotListen,
    ConfigError,
    ControlUnavailable,
    FeatureFailed,
    StoreRefused,
)
from gateway.event_loop import EventLoopChoice, choose_event_loop
from gateway.event_loop import run as run_on_loop
from gateway.exit_codes import EXIT_CONFIG, EXIT_FAILURE, EXIT_OK, EXIT_STARTUP
from gateway.health import Phase
from gateway.large_allocations import give_back_large_allocations
from gateway.logs import setup_logging
from gateway.memory_trace import trace_from_environment
from gateway.settings import runtime_settings
from gateway.systemd import Notifier, keep_watchdog, watchdog_interval_s

log = logging.getLogger(__name__)


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "run",
        help="run the gateway service",
        description="Run the gateway on the configuration file: the Modbus-TCP server, one "
        "bus per RS-485 line, the poller, and (as configured) the MQTT bridge, the console and "
        "/metrics with /health. Stops cleanly on SIGTERM or Ctrl-C; SIGHUP reloads the file. "
        "Exit codes: 0 stopped, 1 failed while serving (a bus or a feature died), 3 the "
        "configuration does not validate (the key and the reason are printed), 4 could not "
        "start (a port taken or two on one port, a TLS file that can't be used, a store from a "
        "newer release or held by another gateway).",
    )
    parser.add_argument(
        "--config", "-c", default=DEFAULT_CONFIG, help=f"YAML file (default {DEFAULT_CONFIG})"
    )
    parser.set_defaults(handler=handle)


def handle(args: argparse.Namespace) -> int:
    config = load_or_report(args.config)
    if config is None:
        return EXIT_CONFIG
    loop = event_loop_or_report()
    if loop is None:
        return EXIT_CONFIG
    setup_logging(config.logging.level, config.logging.format)
    log.info("event loop: %s", loop.describe())
    log.info("engine room: %s", ENGINE_ROOM)
    give_back_large_allocations()  # a login's 16 MiB of scrypt kept by each thread otherwise
    snapshots = trace_from_environment()
    if snapshots is not None:
        log.warning(
            "tracing memory allocations (slower): SIGUSR2 writes a snapshot to %s", snapshots
        )
    return run_on_loop(serve(config, config_path=args.config), loop)


def event_loop_or_report() -> EventLoopChoice | None:
    """The loop `INVT_GATEWAY_EVENT_LOOP` asks for; None (and why, on stderr) if it can't be."""
    try:
        return choose_event_loop()
    except ConfigError as exc:
        print(f"invt-gateway: {exc}", file=sys.stderr)
        return None


def load_or_report(path: str) -> GatewayConfig | None:
    try:
        return load_config(path)
    except ConfigError as exc:
        print(f"invt-gateway: {exc}", file=sys.stderr)
        return None


async def serve(
    config: GatewayConfig,
    on_ready: Callable[[Application], None] | None = None,
    config_path: str | None = None,
    flags: Mapping[str, str] | None = None,
) -> int:
    """Run the gateway until SIGTERM or SIGINT; the exit code.

    Under systemd (`Type=notify`) it reports READY=1 once the buses and the TCP port are up,
    STOPPING=1 on the signal, and pings the watchdog from this event loop meanwhile. SIGHUP,
    or `invt-gateway reload` on the control socket (`gateway.control`), reads `config_path`
    again and applies it in place (`Application.reload`); a file that doesn't validate changes
    nothing and is logged (and answered, on the socket) with each key path and reason.

    `flags`: the configuration keys a command's own options set (`demo --port` sets
    `modbus_tcp.port`): an error that names such a key names the option too, since the user
    typed the option and may never have seen the key.
    """
    if not await can_start(config, flags):
        return EXIT_STARTUP
    app = Application(runtime_settings(config))
    notifier = Notifier.from_environment()
    reloader = Reloader(app, config_path, notifier)
    _edit_from_console(app, config_path, reloader)
    with Signals(notifier) as signals:
        control = await listen_for_control(config_path, reloader)
        try:
            work = beside_the_service(reloader, signals.reload_asked, notifier)
            ready = announce_ready(app, config, notifier, on_ready)
            return await run_to_exit_code(app, signals.stop, ready, work, flags)
        finally:
            if control is not None:
                await control.stop()
            notifier.close()


async def can_start(config: GatewayConfig, flags: Mapping[str, str] | None) -> bool:
    """What binding and loading would find one at a time, said at once, before anything
    started: the same lines check-config and the console give."""
    problems = await asyncio.to_thread(startup_problems, config)
    for key, reason in problems:
        log.error("cannot start: %s", naming_flags(f"{key}: {reason}", flags))
    return not problems


class Signals:
    """SIGTERM and SIGINT set `stop` (STOPPING=1 to systemd, once); SIGHUP sets
    `reload_asked`. The handlers are this loop's while the block runs, and removed after."""

    def __init__(self, notifier: Notifier) -> None:
        self.notifier = notifier
        self.stop = asyncio.Event()
        self.reload_asked = asyncio.Event()
        self._loop = asyncio.get_running_loop()

    def __enter__(self) -> Signals:
        for signum in (signal.SIGTERM, signal.SIGINT):
            self._loop.add_signal_handler(signum, self._stop, signum)
        self._loop.add_signal_handler(signal.SIGHUP, self.reload_asked.set)
        return self

    def __exit__(self, *exc_info: object) -> None:
        for signum in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP):
            self._loop.remove_signal_handler(signum)

    def _stop(self, signum: signal.Signals) -> None:
        if not self.stop.is_set():
            log.info("%s received: shutting down", signum.name)
            self.notifier.stopping()
        self.stop.set()


def announce_ready(
    app: Application,
    config: GatewayConfig,
    notifier: Notifier,
    on_ready: Callable[[Application], None] | None,
) -> Callable[[], None]:
    """What runs once the gateway is ready: the log line, READY=1, and the caller's own."""

    def ready() -> None:
        status = (
            f"ready: {len(config.drives)} drives on {len(config.buses)} buses, "
            f"Modbus-TCP on {config.modbus_tcp.host}:{app.tcp.port}"
        )
        log.info("%s", status)
        notifier.ready(status)
        settle_startup_objects()
        if on_ready is not None:
            on_ready(app)

    return ready


def beside_the_service(
    reloader: Reloader, reload_asked: asyncio.Event, notifier: Notifier
) -> dict[str, Coroutine[Any, Any, None]]:
    """The service's own work, by task name, for the application's TaskGroup: a bug in either
    stops the service, saying so, rather than leaving it deaf to SIGHUP or killed later by the
    watchdog without a reason."""
    work = {"reload": reloader.on_hangup(reload_asked)}
    interval_s = watchdog_interval_s()
    if interval_s is not None and notifier.enabled:
        work["systemd-watchdog"] = keep_watchdog(notifier, interval_s)
    return work


async def run_to_exit_code(
    app: Application,
    stop: asyncio.Event,
    ready: Callable[[], None],
    alongside: Mapping[str, Coroutine[Any, Any, None]],
    flags: Mapping[str, str] | None,
) -> int:
    """The application run until `stop`; its failures turned into the exit codes the service
    manager reads (`gateway.exit_codes`)."""
    try:
        await app.run(stop, ready, alongside)
    except OSError as exc:
        log.error("cannot start: %s", exc)
        return EXIT_STARTUP
    except ExceptionGroup as group:
        unbound = group.subgroup((CannotListen, StoreRefused, BrokerShared))
        if unbound is not None:
            # A port taken or a wrong address, a store of a newer release: one line that says
            # which and why, no traceback.
            log.error("cannot start: %s", naming_flags(str(unbound.exceptions[0]), flags))
            return EXIT_STARTUP
        failed = group.subgroup((BusFailed, FeatureFailed))
        if failed is None:
            raise
        # Exit non-zero so the service manager restarts the gateway (Restart=on-failure).
        log.critical("stopping: %s", failed.exceptions[0])
        return EXIT_FAILURE
    return EXIT_OK


def naming_flags(message: str, flags: Mapping[str, str] | None) -> str:
    """`message` with, after it, the option that sets each configuration key it names:
    "... change modbus_tcp.host/port (or the option --port)"."""
    named = [flag for key, flag in (flags or {}).items() if key in message]
    return f"{message} (or the option {', '.join(named)})" if named else message


def _edit_from_console(app: Application, path: str | None, reloader: Reloader) -> None:
    """The console's admins edit the file the gateway runs with, applied by the same reload."""
    console = app.console
    if console is None or path is None:
        return
    from gateway.console.config_editor import ConfigEditor
    from gateway.console.sealing import SecretSeal

    console.config_editor = ConfigEditor(
        path,
        reloader.reload,
        app.events,
        lambda: app.settings,
        lambda: app.mqtt is not None,
        SecretSeal(lambda: app.events.path if app.events.persistent else None),
    )


async def listen_for_control(path: str | None, reloader: Reloader) -> ControlServer | None:
    """The control socket `invt-gateway reload` asks on; without it SIGHUP still reloads."""
    if path is None:
        return None
    control = ControlServer(path, reloader.on_command)
    try:
        await control.start()
    except ControlUnavailable as exc:
        log.warning("no control socket, `invt-gateway reload` can't reach this gateway: %s", exc)
        return None
    return control


class Reloader:
    """Reads the file again and applies it, one reload at a time, whoever asks: SIGHUP (whose
    sender hears nothing back) or `invt-gateway reload` on the control socket (which hears the
    answer, and exits non-zero when the file was refused)."""

    def __init__(self, app: Application, path: str | None, notifier: Notifier) -> None:
        self.app = app
        self.path = path
        self.notifier = notifier
        self._one_at_a_time = asyncio.Lock()

    async def on_hangup(self, asked: asyncio.Event) -> None:
        """Each SIGHUP: a reload, its outcome in the log only."""
        while True:
            await asked.wait()
            asked.clear()
            log.info("SIGHUP received")
            await self.reload()

    async def on_command(self, command: str) -> list[str]:
        words = command.split()
        if words and words[0] == ROLE:
            return self.role(words[1:])
        if command != RELOAD:
            return [f"refused: unknown command {command!r} (known: {RELOAD}, {ROLE})"]
        log.info("reload asked on the control socket")
        return await self.reload()

    def role(self, words: list[str]) -> list[str]:
        """`role active|standby|status`, for a gateway with `redundancy:` (its `Redundancy`)."""
        redundancy = self.app.redundancy
        if redundancy is None:
            return ["refused: redundancy is not enabled here (redundancy.enabled: true)"]
        if len(words) != 1:
            return ["refused: role takes one word: active, standby or status"]
        log.info("role %s asked on the control socket", words[0])
        return redundancy.ask(words[0])

    async def reload(self) -> list[str]:
        """Read the file again (off the event loop) and apply it if it is valid; the outcome,
        one line each, starting with applied, refused or skipped."""
        async with self._one_at_a_time:
            if self.path is None:
                log.warning("reload skipped: no configuration file to read again")
                return ["skipped: no configuration file to read again"]
            self.notifier.notify("RELOADING=1", "STATUS=reloading the configuration")
            try:
                return await self._reload(self.path)
            finally:
                self.notifier.notify("READY=1", "STATUS=ready")

    async def _reload(self, path: str) -> list[str]:
        log.info("reading %s again", path)
        try:
            config = await asyncio.to_thread(load_config, path)
            problems = await asyncio.to_thread(startup_problems, config)
            if problems:
                # Applied, it would run, and the next start would fail on it.
                raise ConfigError(problems, path)
        except ConfigError as exc:
            # As check-config says it: every problem, with its key path, one line each (the
            # journal shows a line at a time). Nothing changes.
            answer = []
            for key, reason in exc.problems:
                problem = f"{key}: {reason}" if key else reason
                log.error("reload refused, the running configuration stays: %s: %s", path, problem)
                answer.append(f"refused: {path}: {problem}")
            return answer
        if self.app.phase is not Phase.READY:
            log.warning("reload skipped: the gateway is %s", self.app.phase.value)
            return [f"skipped: the gateway is {self.app.phase.value}"]
        redundancy = self.app.redundancy
        if redundancy is not None and not redundancy.serving:
            # Its buses, poller and bridge are built anew at its next start: a standby's
            # restart costs nothing (the active one keeps the line), a half-applied reload might.
            why = f"this gateway is {redundancy.role.value}: restart it to apply the file"
            log.warning("reload skipped: %s", why)
            return [f"skipped: {why}"]
        try:
            plan = await self.app.reload(runtime_settings(config))
        except BrokerShared as exc:
            # The new MQTT settings would take another live gateway's place: nothing changed.
            log.error("reload refused, the running configuration stays: %s: %s", path, exc)
            return [f"refused: {path}: {exc}"]
        return [f"applied: {plan.summary}"]
