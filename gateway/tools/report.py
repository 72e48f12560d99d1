"""What a scan prints: the table of drives found, or why none was."""

from __future__ import annotations

from rich import box
from rich.table import Table

from gateway.bus.line import BURSTS_FROM_S, SerialLine
from gateway.errors import FieldError
from gateway.tools.advice import COMMUNICATION_MODE, GARBLED, NO_ANSWER
from gateway.tools.masters import SerialOptions
from gateway.tools.scan import ScanResult


def result_table(options: SerialOptions, result: ScanResult) -> Table:
    table = Table(
        title=f"{len(result.found)} drive(s) on {options.describe()}",
        box=box.SIMPLE,
        title_justify="left",
    )
    notes = any(drive.note for drive in result.found)
    columns = ["address", "model", "state", "fault", "command source"] + (["note"] if notes else [])
    for column in columns:
        table.add_column(column, justify="right" if column == "address" else "left")
    table.columns[1].no_wrap = True  # "GD30 (01F0H unconfirmed)": one cell, one line
    table.columns[3].no_wrap = True  # "STo: maladjustment" reads badly on two lines
    for drive in result.found:
        cells = [
            str(drive.address),
            drive.model,
            drive.state,
            drive.fault_text,
            drive.command_source,
        ]
        table.add_row(*cells, *([drive.note] if notes else []))
    if any(d.command_source not in ("communication", "-") for d in result.found):
        table.caption = "Drives not on communication ignore Modbus commands: " + "; ".join(
            COMMUNICATION_MODE
        )
    return table


def no_drive_found(options: SerialOptions, result: ScanResult) -> FieldError:
    if result.garbled:
        addresses = ", ".join(map(str, result.garbled[:10]))
        return FieldError(
            f"no drive answered properly on {options.describe()}, but garbled replies came "
            f"at address {addresses}",
            GARBLED,
        )
    delay = (
        f"the drives' response delay P14.03 is below --timeout-ms ({options.timeout_s * 1000:g} ms)"
    )
    return FieldError(f"no drive answered on {options.describe()}", (*NO_ANSWER, delay))


def line_notes(line: SerialLine) -> list[str]:
    """What the scan learnt about the line's hardware, and what to set for it."""
    notes = []
    if line.echo_detected:
        notes.append(
            "this adapter echoes what is sent (no echo suppression): set `echo: true` for this "
            "bus in the gateway's configuration"
        )
    silence = line.longest_reply_silence_s
    if silence > BURSTS_FROM_S:
        notes.append(
            f"replies arrive in bursts (up to {silence * 1000:.0f} ms of silence inside one): "
            "the gateway reads them whole; for an FTDI adapter set its latency_timer to 1 "
            "(/sys/bus/usb-serial/devices/<ttyUSBn>/latency_timer)"
        )
    if line.garbage_bytes:
        notes.append(
            f"{line.garbage_bytes} stray byte(s) came before replies (a transceiver glitching as "
            "the bus turns around): skipped; check termination and biasing if they are many"
        )
    return notes
