"""`invt-gateway healthcheck [--config FILE]`: exit 0 when the running gateway is ready.

For Docker's HEALTHCHECK (the slim image has no curl): asks /health on the metrics port of the
configuration's gateway. With metrics disabled it checks that the Modbus-TCP port accepts a
connection instead, which still tells a stuck or dead gateway from a working one.

Exit 1 too while the store can't keep events on disk (storage.path can't be opened or written:
the events are in memory only, a restart loses them), with the reason on stderr: "healthy" must
not hide that. An offline drive or a lost port stays exit 0 (degraded in the report): the
gateway serves all it can, and no restart brings a drive back.
"""

from __future__ import annotations

import argparse
import json
import socket
import sys
import urllib.error
import urllib.request

from gateway.commands.run import DEFAULT_CONFIG, load_or_report
from gateway.exit_codes import EXIT_CONFIG, EXIT_FAILURE, EXIT_OK

ANY_ADDRESS = ("0.0.0.0", "::", "")


def register(subparsers: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    parser = subparsers.add_parser(
        "healthcheck",
        help="exit 0 if the gateway of this configuration is up and ready (for Docker)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--config", "-c", default=DEFAULT_CONFIG, help="YAML file")
    parser.add_argument("--timeout", type=float, default=3.0, metavar="S")
    parser.set_defaults(handler=handle)


def local_host(host: str) -> str:
    """Where to reach a server bound to `host` from this machine."""
    return "127.0.0.1" if host in ANY_ADDRESS else host


def handle(args: argparse.Namespace) -> int:
    config = load_or_report(args.config)
    if config is None:
        return EXIT_CONFIG
    if config.metrics.enabled:
        host = local_host(config.metrics.host)
        url = f"http://{host}:{config.metrics.port}/health"
        try:
            with urllib.request.urlopen(url, timeout=args.timeout) as response:
                body = response.read().decode(errors="replace").strip()
            print(body)
            problem = store_problem(body)
            if problem is not None:
                print(f"store: {problem}", file=sys.stderr)
                return EXIT_FAILURE
            return EXIT_OK
        except urllib.error.HTTPError as exc:  # 503: starting or stopping
            print(f"{url}: {exc.code} {exc.read().decode(errors='replace').strip()}")
            return EXIT_FAILURE
        except OSError as exc:
            print(f"{url}: {exc}", file=sys.stderr)
            return EXIT_FAILURE
    tcp = config.modbus_tcp
    address = (local_host(tcp.host), tcp.port)
    try:
        with socket.create_connection(address, timeout=args.timeout):
            print(f"Modbus-TCP {address[0]}:{address[1]} accepts connections")
            return EXIT_OK
    except OSError as exc:
        print(f"Modbus-TCP {address[0]}:{address[1]}: {exc}", file=sys.stderr)
        return EXIT_FAILURE


def store_problem(body: str) -> str | None:
    """Why the store keeps events in memory only, from a /health report; None if it doesn't."""
    try:
        store = json.loads(body).get("store") or {}
    except (ValueError, AttributeError):
        return None
    if store.get("state", "writing") == "writing":
        return None
    return str(store.get("reason") or store.get("state"))
