"""Command-line options the field tools share: which line, at which settings, or which gateway.

Only argparse here: the tools' modules are imported by the handlers, so `invt-gateway --help`
stays fast.
"""

from __future__ import annotations

import argparse

from gateway.tools import SERIAL_TIMEOUT_MS, VIA_TIMEOUT_MS

BAUD_RATES = (1200, 2400, 4800, 9600, 19200, 38400, 57600, 115200)
"""P14.01's choices."""
PARITIES = ("N", "E", "O")


def add_serial_arguments(
    parser: argparse.ArgumentParser,
    *,
    timeout_ms: float | None,
    timeout_help: str,
    required: bool = True,
) -> None:
    parser.add_argument(
        "--port",
        metavar="DEV",
        required=required,
        help="serial device, e.g. /dev/serial/by-id/usb-FTDI_...-port0 or /dev/ttyUSB0",
    )
    parser.add_argument(
        "--baud",
        type=int,
        default=19200,
        choices=BAUD_RATES,
        metavar="BAUD",
        help="baud rate, as the drives' P14.01 (default 19200)",
    )
    parser.add_argument(
        "--parity",
        default="E",
        type=str.upper,
        choices=PARITIES,
        help="parity, as the drives' P14.02 (default E: E81)",
    )
    parser.add_argument("--stopbits", type=int, default=1, choices=(1, 2))
    parser.add_argument(
        "--timeout-ms",
        type=float,
        default=timeout_ms,
        metavar="MS",
        help=f"response timeout per request ({timeout_help}); "
        "must exceed the drives' response delay P14.03",
    )
    parser.add_argument(
        "--char-timeout-ms",
        type=float,
        default=20.0,
        metavar="MS",
        help="silence that ends a reply of unknown length (default 20); replies of known "
        "length are read whole up to the response timeout, however the adapter bursts them",
    )


def add_target_arguments(parser: argparse.ArgumentParser) -> None:
    """--port ... or --via tcp://HOST:PORT, and --address."""
    parser.add_argument(
        "--via",
        metavar="tcp://HOST:PORT",
        help="go through a running gateway instead of opening the line (address = unit id)",
    )
    parser.add_argument(
        "--address",
        "-a",
        type=int,
        default=1,
        metavar="N",
        help="drive address P14.00, or its unit id with --via (default 1)",
    )
    add_serial_arguments(
        parser,
        timeout_ms=None,
        timeout_help=f"default {SERIAL_TIMEOUT_MS:g}, {VIA_TIMEOUT_MS:g} with --via",
        required=False,
    )
