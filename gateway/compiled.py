"""The engine room compiled to C by mypyc, where the package was built with a C compiler and
Python's headers, and whether the compiled modules beside the sources are of those very sources.

A transaction crosses these modules (the bus and its rooms, Modbus framing, the router, a
Modbus-TCP connection): mypyc compiles them from the same source, typed as it is, which takes a
transaction from about 107,000 interpreted instructions to about 68,000 on uvloop (the Benchmark
page). Nothing else changes: where no compiler was at hand (Debian without python3-dev, a
32-bit ARM box), the same modules run as Python, as they always have.

Python imports a compiled module in preference to its source. A checkout whose sources were
edited after `pip install -e .` compiled them would run the old code without a word, so the
compiled modules are trusted only when the shared library they call into is named for the digest
of today's sources; otherwise every one of them is imported from its source (all or none: the
compiled ones call each other directly, never through an interpreted twin).
"""

from __future__ import annotations

import hashlib
import importlib.machinery
import importlib.util
import os
import sys
from collections.abc import Sequence
from pathlib import Path
from types import ModuleType

COMPILED_MODULES: tuple[str, ...] = (
    "gateway.buckets",
    "gateway.timerfd",
    "gateway.modbus.crc",
    "gateway.modbus.functions",
    "gateway.modbus.mbap",
    "gateway.modbus.rtu",
    "gateway.bus.bus",
    "gateway.bus.carrier",
    "gateway.bus.dispatch",
    "gateway.bus.exchange",
    "gateway.bus.gap_excess",
    "gateway.bus.gap_keeper",
    "gateway.bus.gap_lead",
    "gateway.bus.health",
    "gateway.bus.line",
    "gateway.bus.line_share",
    "gateway.bus.line_timer",
    "gateway.bus.observers",
    "gateway.bus.port",
    "gateway.bus.queue",
    "gateway.bus.receiver",
    "gateway.bus.request_metrics",
    "gateway.bus.stats",
    "gateway.bus.wakeup",
    "gateway.routing.router",
    "gateway.tcp.connection",
)
"""The modules mypyc compiles: those a transaction's every step crosses, fully typed."""

PURE_PYTHON_ENV = "INVT_GATEWAY_PURE_PYTHON"
"""Set (to anything but empty): build without compiling, and run the sources even where
compiled modules are present (to compare, or to rule the compiled build out)."""

COMPILED = "compiled by mypyc"
"""What `choose_engine_room` says of a compiled engine room (else "Python (why)")."""

PACKAGE = Path(__file__).resolve().parent
LIBRARY_STEM = "_engine_"
"""The shared library is gateway/_engine_<digest>__mypyc<suffix> (mypyc adds "__mypyc")."""


def source_path(module: str, package: Path = PACKAGE) -> Path:
    return package.parent.joinpath(*module.split(".")).with_suffix(".py")


def source_digest(package: Path = PACKAGE) -> str:
    """The digest of the compiled modules' names and sources, as the build names its library."""
    digest = hashlib.sha256()
    for module in COMPILED_MODULES:
        digest.update(module.encode() + b"\0" + source_path(module, package).read_bytes() + b"\0")
    return digest.hexdigest()[:20]


def library_group(digest: str) -> str:
    """The library's module name, as mypyc's group name: gateway._engine_<digest>."""
    return f"gateway.{LIBRARY_STEM}{digest}"


def compiled_libraries(package: Path = PACKAGE) -> list[Path]:
    """The engine libraries this interpreter could load (of any source)."""
    suffixes = tuple(importlib.machinery.EXTENSION_SUFFIXES)
    return sorted(
        path for path in package.glob(f"{LIBRARY_STEM}*__mypyc*") if path.name.endswith(suffixes)
    )


def built_from_these_sources(libraries: list[Path], package: Path = PACKAGE) -> bool:
    """One of `libraries` (`compiled_libraries`) is the one built from today's sources."""
    fresh = f"{LIBRARY_STEM}{source_digest(package)}__mypyc"
    return any(path.name.startswith(fresh) for path in libraries)


class _SourcesFirst:
    """Imports the compiled modules from their sources, past the compiled files beside them (a
    meta path finder: importlib.abc's base class would cost the start 14 ms of imports)."""

    def __init__(self, package: Path) -> None:
        self.package = package

    def find_spec(
        self, fullname: str, path: Sequence[str] | None, target: ModuleType | None = None
    ) -> importlib.machinery.ModuleSpec | None:
        if fullname not in COMPILED_MODULES:
            return None
        return importlib.util.spec_from_file_location(fullname, source_path(fullname, self.package))


def choose_engine_room(package: Path = PACKAGE) -> str:
    """Decide, before any compiled module is imported, whether they are; say which, and why."""
    libraries = compiled_libraries(package)
    if not libraries:  # (the finder still: a build that failed half-way may have left modules)
        reason = "not compiled: built without a C compiler or Python's headers"
    elif os.environ.get(PURE_PYTHON_ENV):
        reason = f"{PURE_PYTHON_ENV} is set"
    elif built_from_these_sources(libraries, package):
        return COMPILED
    else:
        reason = "its compiled modules are of other sources: `pip install -e .` compiles them again"
    sys.meta_path.insert(0, _SourcesFirst(package))
    return f"Python ({reason})"
