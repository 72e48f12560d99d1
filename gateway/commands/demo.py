"""`invt-gateway demo`: the gateway on simulated drives, nothing else needed.

Starts one simulated INVT line (a pty) per bus of the demo configuration, points the bus at it and
runs the gateway, so a newcomer can read a drive with any Modbus client within a minute.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import sys
from importlib import resources
from pathlib import Path

from gateway.app import Application
from gateway.cli import EXIT_CONFIG
from gateway.commands.run import serve
from gateway.config import GatewayConfig, parse_config
from gateway.errors import ConfigError
from gateway.logs import setup_logging


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "demo", help="run the gateway on simulated drives (no hardware needed)"
    )
    parser.add_argument(
        "--config", "-c", help="configuration to simulate (default: the embedded demo.yaml)"
    )
    parser.add_argument("--port", type=int, help="Modbus-TCP port (default from the config)")
    parser.add_argument(
        "--watch", action="store_true", help="print every MQTT message of the gateway here"
    )
    parser.set_defaults(handler=handle)


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
    if args.port is not None:
        config = config.model_copy(
            update={"modbus_tcp": config.modbus_tcp.model_copy(update={"port": args.port})}
        )
    setup_logging(config.logging.level, config.logging.format)
    with contextlib.ExitStack() as stack:
        config = simulate_buses(config, stack)
        return asyncio.run(serve_demo(config, watch=args.watch))


async def serve_demo(config: GatewayConfig, watch: bool = False) -> int:
    """Serve the demo; with MQTT configured, against a broker even on a machine that has none."""
    mqtt = config.mqtt
    if mqtt is None or not mqtt.enabled:
        return await serve(config, on_ready=lambda app: print_banner(app, config))
    from gateway.mqtt.demo_broker import broker_for_demo, watch_messages

    broker = await broker_for_demo(mqtt)
    config = config.model_copy(update={"mqtt": broker.config})
    watcher = None
    if watch:
        topic = f"{broker.config.base_topic}/#"
        watcher = asyncio.create_task(watch_messages(broker.config, topic), name="demo:watch")
    try:
        return await serve(config, on_ready=lambda app: print_banner(app, config, broker.note))
    finally:
        if watcher is not None:
            watcher.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await watcher
        if broker.embedded is not None:
            await broker.embedded.stop()


def simulate_buses(config: GatewayConfig, stack: contextlib.ExitStack) -> GatewayConfig:
    """Start a simulated line for each bus and return the config pointing at them."""
    from gateway.simulator import SimulatedLine  # only the demo needs the simulator loaded

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
        line.start()
        stack.callback(line.stop)
        buses.append(bus.model_copy(update={"port": line.path}))
    return config.model_copy(update={"buses": tuple(buses)})


def print_banner(app: Application, config: GatewayConfig, mqtt_note: str | None = None) -> None:
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
    lines += [
        "Read state word 1 (2100H) of drive 1:",
        f"  mbpoll -m tcp -p {port} -a 1 -0 -r 0x2100 -c 1 -1 {host}",
        "Start it forward at 25.00 Hz (control word 2000H = 1, set-point 2001H = 2500):",
        f"  mbpoll -m tcp -p {port} -a 1 -0 -r 0x2000 {host} 1 2500",
    ]
    if mqtt_note is not None and config.mqtt is not None:
        lines += mqtt_banner(config, mqtt_note)
    lines += [
        "Stop with Ctrl-C.",
        "",
    ]
    print("\n".join(lines), flush=True)


def mqtt_banner(config: GatewayConfig, note: str) -> list[str]:
    assert config.mqtt is not None
    mqtt = config.mqtt
    base = mqtt.base_topic
    first = config.drives[0].name if config.drives else "pump1"
    where = f"-h {mqtt.host} -p {mqtt.port}"
    run = '{"command": "run_forward", "frequency_hz": 25.0, "transaction": "t1"}'
    return [
        f"{note}; telemetry under {base}/:",
        f"  mosquitto_sub {where} -t '{base}/#' -v      (or: invt-gateway demo --watch)",
        f"Start {first} forward at 25.00 Hz over MQTT (answer on {base}/{first}/set/response):",
        f"  mosquitto_pub {where} -t {base}/{first}/set -m '{run}'",
    ]
