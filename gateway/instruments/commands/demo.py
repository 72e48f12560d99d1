"""`invt-gateway demo`: the gateway on simulated drives, nothing else needed.

Starts one simulated INVT line (a pty) per bus of the demo configuration, points the bus at it and
runs the gateway, so a newcomer can read a drive with any Modbus client within a minute.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import secrets
import shutil
import sys
import tempfile
import uuid
from importlib import resources
from pathlib import Path
from typing import Any, Final, Literal

import yaml
from pydantic import ValidationError

from gateway.app import Application
from gateway.commands.run import event_loop_or_report, serve
from gateway.config import GatewayConfig, MqttConfig, parse_config
from gateway.errors import ConfigError, OptionRefused
from gateway.event_loop import run as run_on_loop
from gateway.exit_codes import EXIT_CONFIG, EXIT_FAILURE, EXIT_OK, EXIT_USAGE
from gateway.logs import setup_logging

DEMO_OPERATOR = "operator"
DEMO_ADMIN = "admin"
DEMO_LOGINS: Final[dict[str, Literal["operator", "admin"]]] = {
    DEMO_OPERATOR: "operator",
    DEMO_ADMIN: "admin",
}
"""The demo's own console users, each with a fresh password at every start: name to role."""
DEMO_MQTT_PORT = 1883
"""The embedded demo.yaml's broker port: `demo --watch` without options looks there."""

log = logging.getLogger(__name__)


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "demo",
        help="run the gateway on simulated drives (no hardware needed)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--config", "-c", help="configuration to simulate (default: the embedded demo.yaml)"
    )
    parser.add_argument("--port", type=int, help="Modbus-TCP port (default from the config: 5020)")
    parser.add_argument(
        "--mqtt-port",
        type=int,
        help="the MQTT broker's port, used or started (default from the config: 1883)",
    )
    parser.add_argument(
        "--console-port",
        type=int,
        help="the console's port (default from the config: 8080; 0 picks a free one)",
    )
    parser.add_argument(
        "--watch",
        action="store_true",
        help="watch a running demo: print every MQTT message under its base topic "
        "(starts no gateway)",
    )
    adapter = parser.add_argument_group(
        "real hardware", "show what common RS-485 hardware does to the line, and the gateway coping"
    )
    adapter.add_argument(
        "--burst-ms",
        type=not_negative_ms,
        default=0.0,
        metavar="MS",
        help="the adapter hands replies over in bursts every MS ms (a USB latency timer)",
    )
    adapter.add_argument(
        "--glitch",
        action="store_true",
        help="a transceiver glitch byte (FFH) before every reply",
    )
    adapter.add_argument(
        "--echo", action="store_true", help="the adapter echoes every request (echo: false)"
    )
    parser.set_defaults(handler=handle)


def not_negative_ms(text: str) -> float:
    """A duration option: argparse names the option when this refuses the value."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of milliseconds") from None
    if not value >= 0:  # NaN too
        raise argparse.ArgumentTypeError(f"{text}: must be 0 or more")
    return value


def demo_config_text(path: str | None) -> str:
    if path is not None:
        return Path(path).read_text(encoding="utf-8")
    return resources.files("gateway").joinpath("data/demo.yaml").read_text(encoding="utf-8")


def handle(args: argparse.Namespace) -> int:
    try:
        config = parse_config(demo_config_text(args.config), args.config or "demo.yaml")
    except (ConfigError, OSError) as exc:
        print(f"invt-gateway: {exc}", file=sys.stderr)
        return EXIT_CONFIG
    listed = config.mqtt.servers if config.mqtt is not None else None
    if config.mqtt is not None:
        config = config.model_copy(update={"mqtt": one_broker(config.mqtt)})
    try:
        config = with_options(config, args)
    except OptionRefused as exc:
        print(f"invt-gateway demo: {exc}", file=sys.stderr)
        return EXIT_USAGE
    loop = event_loop_or_report()
    if loop is None:
        return EXIT_CONFIG
    setup_logging(config.logging.level, config.logging.format)
    if listed is not None and len(listed) > 1:
        log.warning(
            "demo: mqtt.servers lists %d brokers; the demo uses one, the first: %s",
            len(listed),
            listed[0],
        )
    if args.watch:
        return asyncio.run(watch_demo(config))
    with contextlib.ExitStack() as stack:
        adapter = {
            "burst_ms": args.burst_ms,
            "glitch": b"\xff" if args.glitch else b"",
            "echo": args.echo,
        }
        config = simulate_buses(config, stack, adapter)
        # The demo's own folder, gone with it: its store, and the copy of its configuration
        # the console's admin edits.
        folder = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="invt-gateway-demo-")))
        if config.storage.path is None:
            storage = config.storage.model_copy(update={"path": str(folder / "events.db")})
            config = config.model_copy(update={"storage": storage})
        config, logins = with_demo_logins(config)
        log.info("event loop: %s", loop.describe())
        return run_on_loop(serve_demo(config, args.config, logins, folder), loop)


def one_broker(mqtt: MqttConfig) -> MqttConfig:
    """The demo's one broker, as `host`/`port`: what it probes, starts in its place when none
    answers (possibly on another port), shows in the banner and watches, and what the gateway
    then connects to; `--mqtt-port` then changes its port. A configuration listing
    `mqtt.servers` (a cluster's nodes) runs the demo on the first of them: without this the
    demo rewrote `host`/`port` while the gateway went on with the list, away from the broker
    it had started (and `--mqtt-port` was refused beside the list)."""
    host, port = mqtt.broker_addresses()[0]
    return mqtt.model_copy(update={"servers": None, "host": host, "port": port})


OPTIONS = {"port": ("modbus_tcp", "port"), "mqtt_port": ("mqtt", "port"),
           "console_port": ("console", "port")}  # fmt: skip
"""Each of the demo's options that sets a configuration key: its section and key."""
LISTEN_FLAGS = {"modbus_tcp.host/port": "--port", "console.host/port": "--console-port"}
"""What an error at start names (`gateway.listen`), and the demo's option that changes it."""


def with_options(config: GatewayConfig, args: argparse.Namespace) -> GatewayConfig:
    """The configuration with the ports the options give, each checked as the file's key would
    be (`--port 70000` is refused, not wrapped around to 4464); the error names the option."""
    for option, (section_name, key) in OPTIONS.items():
        value = getattr(args, option)
        section = getattr(config, section_name)
        flag = "--" + option.replace("_", "-")
        if value is None:
            continue
        if section is None:
            raise OptionRefused(f"{flag} {value}: this configuration has no {section_name} section")
        try:
            checked = type(section).model_validate(
                {**section.model_dump(exclude_unset=True), key: value}
            )
        except ValidationError as exc:
            reasons = "; ".join(error["msg"] for error in exc.errors())
            raise OptionRefused(f"{flag} {value}: {reasons} ({section_name}.{key})") from None
        config = config.model_copy(update={section_name: checked})
    return config


async def watch_demo(config: GatewayConfig) -> int:
    """`demo --watch`: print the running demo's MQTT messages until Ctrl-C; no gateway here.

    A second gateway would find the demo's Modbus-TCP port taken; watching needs only the broker.
    """
    if config.mqtt is None or not config.mqtt.enabled:
        print("invt-gateway demo --watch: this configuration has no MQTT", file=sys.stderr)
        return EXIT_FAILURE
    from gateway.instruments.demo_broker import watch_messages

    await watch_messages(config.mqtt, f"{config.mqtt.base_topic}/#", status=sys.stderr)
    return EXIT_OK


def with_demo_logins(config: GatewayConfig) -> tuple[GatewayConfig, dict[str, str]]:
    """With the console on, a user "operator" and a user "admin", each with a fresh random
    password (printed in the banner): operator actions and configuration edits always need a
    login, even in the demo. A user of that name in the configuration is left as it is (no
    password printed for it)."""
    console = config.console
    if not console.enabled:
        return config, {}
    from gateway.config import ConsoleUserConfig
    from gateway.passwords import hash_password

    taken = {user.name for user in console.users}
    logins = {name: secrets.token_urlsafe(9) for name in DEMO_LOGINS if name not in taken}
    added = tuple(
        ConsoleUserConfig(name=name, password_hash=hash_password(password), role=DEMO_LOGINS[name])
        for name, password in logins.items()
    )
    console = console.model_copy(update={"users": (*console.users, *added)})
    return config.model_copy(update={"console": console}), logins


def editable_copy(config: GatewayConfig, folder: Path) -> str:
    """The demo's configuration as it runs (its simulated lines, store, logins) written to
    `folder`: the file the console's admin edits and the reload reads. The file given with
    --config, or the packaged one, stays as it is."""
    path = folder / "config.yaml"
    data = config.model_dump(mode="json", exclude_unset=True)
    path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return str(path)


async def serve_demo(
    config: GatewayConfig,
    config_path: str | None = None,
    logins: dict[str, str] | None = None,
    folder: Path | None = None,
) -> int:
    """Serve the demo; with MQTT configured, against a broker even on a machine that has none.
    `folder`: where the copy of the configuration the console edits goes (None: no editing)."""
    logins = logins or {}
    mqtt = config.mqtt
    if mqtt is None or not mqtt.enabled:
        edited = None if folder is None else editable_copy(config, folder)
        return await serve(
            config,
            on_ready=lambda app: print_banner(app, config, None, logins, edited),
            config_path=edited,
            flags=LISTEN_FLAGS,
        )
    from gateway.instruments.demo_broker import broker_for_demo, clear_discovery

    broker = await broker_for_demo(mqtt)
    mqtt = broker.config
    if mqtt.client_id is None:
        # Two demos on one broker (or a demo beside a service with gateway_id "demo") must not
        # share a client id: the broker would keep throwing one off for the other. The
        # service's documented default (invt-gateway-<gateway_id>) is for one gateway per id.
        unique = f"invt-gateway-{config.gateway_id}-{uuid.uuid4().hex[:8]}"
        mqtt = mqtt.model_copy(update={"client_id": unique})
    config = config.model_copy(update={"mqtt": mqtt})
    edited = None if folder is None else editable_copy(config, folder)
    started = False

    def ready(app: Application) -> None:
        nonlocal started
        started = True
        print_banner(app, config, (broker.note, watch), logins, edited)

    try:
        watch = watch_command(config_path, mqtt.port)
        return await serve(config, on_ready=ready, config_path=edited, flags=LISTEN_FLAGS)
    finally:
        if broker.embedded is not None:
            await broker.embedded.stop()
        elif started:
            # Only a demo that started has entities of its own to clear: one that failed to
            # start (a port taken, another demo live with its gateway id: refused before it
            # published anything) would clear those of the demo already running.
            await clear_discovery(mqtt, config.gateway_id)


def simulate_buses(
    config: GatewayConfig,
    stack: contextlib.ExitStack,
    adapter: dict[str, Any] | None = None,
) -> GatewayConfig:
    """Start a simulated line for each bus and return the config pointing at them; `adapter`:
    `SimulatedLine.set_adapter`'s options, for every line."""
    from gateway.instruments.simulator import (
        SimulatedLine,  # only the demo needs the simulator loaded
    )

    buses = []
    for bus in config.buses:
        drives = [d for d in config.drives if d.bus == bus.name]
        line = SimulatedLine(
            addresses=[d.address for d in drives],
            models={d.address: d.model for d in drives},
            baudrate=bus.baudrate,
            parity=bus.parity,
            stopbits=bus.stopbits,
            wire_time=True,
        )
        if adapter and any(adapter.values()):
            line.set_adapter(**adapter)
        line.start()
        stack.callback(line.stop)
        buses.append(bus.model_copy(update={"port": line.path}))
    return config.model_copy(update={"buses": tuple(buses)})


def watch_command(config_path: str | None, mqtt_port: int) -> str:
    """The `demo --watch` line that finds this demo's broker and topics."""
    command = f"{own_command()} demo --watch"
    if config_path is not None:
        command += f" --config {config_path}"
    if config_path is not None or mqtt_port != DEMO_MQTT_PORT:
        command += f" --mqtt-port {mqtt_port}"
    return command


def print_banner(
    app: Application,
    config: GatewayConfig,
    mqtt_note: tuple[str, str] | None = None,
    logins: dict[str, str] | None = None,
    edited: str | None = None,
) -> None:
    """`logins`: the demo's own users and their passwords; `edited`: the file the console's
    admin edits."""
    logins = logins or {}
    host = config.modbus_tcp.host
    port = app.tcp.port
    lines = [
        "",
        f"invt-gateway demo: Modbus-TCP on {host}:{port}, simulated drives:",
    ]
    for drive in config.drives:
        bus = next(b for b in config.buses if b.name == drive.bus)
        lines.append(
            f"  unit id {drive.effective_unit_id:>3}  {drive.name:<10} {drive.model:<7} "
            f"address {drive.address} on {bus.name} ({bus.port}, {bus.baudrate} baud)"
        )
    me = own_command()
    via = f"--via tcp://{host}:{port} --address 1"
    lines += [
        "Read state word 1 (2100H) of drive 1 (3 = stopped), in another terminal:",
        f"  {me} read {via} 2100H        (or: mbpoll -m tcp -p {port} -a 1 -0 -r 0x2100 -c 1 -1 "
        f"{host})",
        "Start it forward at 25.00 Hz (control word 2000H, set-point 2001H), read its frequency:",
        f"  {me} write {via} frequency_setpoint=25.00 control_word=run_forward",
        f"  {me} read {via} output_frequency",
    ]
    if mqtt_note is not None and config.mqtt is not None:
        lines += mqtt_banner(config, *mqtt_note)
    console = getattr(app, "console", None)
    if console is not None:
        lines.append(f"The console: open {console.url} in a browser (viewing needs no login).")
        if DEMO_OPERATOR in logins:
            password = logins[DEMO_OPERATOR]
            lines.append(f"  To run, stop or write: log in as {DEMO_OPERATOR}, password {password}")
        if DEMO_ADMIN in logins and edited is not None:
            password = logins[DEMO_ADMIN]
            lines.append(
                f"  To edit the configuration too: log in as {DEMO_ADMIN}, password {password}"
            )
            lines.append(f"    (a copy of the demo's, {edited}, gone when the demo stops)")
        lines.append(f"  Traffic in a terminal: {me} monitor --url {console.url}")
    lines += [
        "Stop with Ctrl-C.",
        "",
    ]
    print("\n".join(lines), flush=True)


def own_command() -> str:
    """How to call this program from another terminal: `invt-gateway` when the PATH finds this
    one, else its full path (installed in a virtual environment that isn't activated)."""
    beside = Path(sys.executable).with_name("invt-gateway")
    found = shutil.which("invt-gateway")
    if not beside.exists() or (found is not None and Path(found).resolve() == beside.resolve()):
        return "invt-gateway"
    if beside.is_relative_to(Path.cwd()):
        return str(beside.relative_to(Path.cwd()))  # .venv/bin/invt-gateway, as in the README
    return str(beside)


def mqtt_banner(config: GatewayConfig, note: str, watch: str) -> list[str]:
    assert config.mqtt is not None
    mqtt = config.mqtt
    base = mqtt.base_topic
    first = config.drives[0].name if config.drives else "pump1"
    where = f"-h {mqtt.host} -p {mqtt.port}"
    run = '{"command": "run_forward", "frequency_hz": 25.0, "transaction": "t1"}'
    return [
        f"{note}; telemetry under {base}/:",
        f"  {watch}      (or: mosquitto_sub {where} -t '{base}/#' -v)",
        f"Start {first} forward at 25.00 Hz over MQTT (answer on {base}/{first}/set/response):",
        f"  mosquitto_pub {where} -t {base}/{first}/set -m '{run}'",
    ]
