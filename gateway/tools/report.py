"""What a scan prints: the table of drives found, or why none was."""

from __future__ import annotations

from rich import box
from rich.table import Table

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
