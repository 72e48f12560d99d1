"""Opening the master a tool's arguments ask for: the serial line, or a gateway via TCP."""

from __future__ import annotations

import argparse

from gateway.errors import FieldError, PortError
from gateway.tools import SERIAL_TIMEOUT_MS, VIA_TIMEOUT_MS
from gateway.tools.advice import GATEWAY, PORT
from gateway.tools.masters import Master, RtuMaster, SerialOptions, TcpMaster, parse_via


def serial_options(args: argparse.Namespace, *, drain_ms: float = 50.0) -> SerialOptions:
    timeout_ms = SERIAL_TIMEOUT_MS if args.timeout_ms is None else args.timeout_ms
    return SerialOptions(
        port=args.port,
        baudrate=args.baud,
        parity=args.parity,
        stopbits=args.stopbits,
        timeout_s=timeout_ms / 1000,
        char_timeout_s=args.char_timeout_ms / 1000,
        drain_s=drain_ms / 1000,
    )


def open_master(args: argparse.Namespace) -> Master:
    """The master for --via or --port; FieldError when neither or both are given, or it fails."""
    if (args.via is None) == (args.port is None):
        raise FieldError("give either --port DEV (the line) or --via tcp://HOST:PORT (a gateway)")
    try:
        if args.via is not None:
            host, port = parse_via(args.via)
            timeout_ms = VIA_TIMEOUT_MS if args.timeout_ms is None else args.timeout_ms
            return TcpMaster(host, port, timeout_ms / 1000)
        return open_serial(serial_options(args))
    except ValueError as exc:
        raise FieldError(str(exc)) from exc
    except PortError as exc:
        raise FieldError(str(exc), GATEWAY if args.via is not None else PORT) from exc


def open_serial(options: SerialOptions) -> RtuMaster:
    try:
        return RtuMaster(options)
    except PortError as exc:
        raise FieldError(str(exc), PORT) from exc
