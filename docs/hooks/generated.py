"""MkDocs hook: the pages' generated parts, made from the code and its data at every build.

A page says where a part goes with an HTML comment alone on its line, `<!-- generated: NAME -->`;
the build puts the part there (so the page can't drift from the code), and fails on a name it
doesn't know, or when the code's facts are incomplete (a configuration key without a
description). Registered in mkdocs.yml (`hooks:`).
"""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

from mkdocs.exceptions import PluginError
from pydantic import BaseModel

from gateway.config import GatewayConfig, reference
from gateway.instruments.bench import page
from gateway.profile import reference as drives
from gateway.profile.device_files import DEVICE_FILE


def configuration_keys() -> str:
    return documented_keys(GatewayConfig, "configuration keys", "Configuration")


def device_file_keys() -> str:
    return documented_keys(DEVICE_FILE, "device-file keys", "Other Modbus devices")


def documented_keys(model: type[BaseModel], what: str, page: str) -> str:
    missing = reference.undocumented(model)
    if missing:
        raise PluginError(
            f"{what} without a description (the {page} page is generated from the models' "
            "field docstrings):\n  " + "\n  ".join(missing)
        )
    return reference.markdown(model, heading="###")


BENCH_RUN = Path(__file__).resolve().parent.parent / "bench" / "run.md"
"""The run `invt-gateway bench --page docs/bench/run.md` wrote, which the Benchmark page shows."""


def benchmark_run() -> str:
    if not BENCH_RUN.is_file():
        raise PluginError(f"{BENCH_RUN} is missing: run invt-gateway bench --page {BENCH_RUN}")
    text = BENCH_RUN.read_text(encoding="utf-8")
    if not text.startswith(page.WRITTEN_BY):
        raise PluginError(f"{BENCH_RUN} was not written by invt-gateway bench --page")
    return text


GENERATORS: dict[str, Callable[[], str]] = {
    "configuration-keys": configuration_keys,
    "device-file-keys": device_file_keys,
    "drive-models": drives.series_markdown,
    "communication-registers": drives.registers_markdown,
    "fault-tables": drives.faults_markdown,
    "parameter-tables": drives.parameters_markdown,
    "benchmark-run": benchmark_run,
}

MARKER = re.compile(r"^<!-- generated: ([\w-]+) -->$", re.MULTILINE)


def on_page_markdown(markdown: str, page: Any, **_: Any) -> str:
    def part(match: re.Match[str]) -> str:
        name = match.group(1)
        if name not in GENERATORS:
            known = ", ".join(GENERATORS)
            raise PluginError(f"{page.file.src_uri}: no generated part {name!r} (known: {known})")
        return GENERATORS[name]()

    return MARKER.sub(part, markdown)
