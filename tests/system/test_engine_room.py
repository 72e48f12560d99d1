"""The engine room compiled by mypyc (gateway/compiled.py, gateway/build_backend.py), as the
process that runs the gateway imports it: compiled where this checkout was built with a C
compiler and Python's headers, its sources when told so, and never a compiled module of older
sources than those beside it.

The compiled build itself is made by the install (`bash .ci/test` installs .venv editable, which
compiles in place; test_ops_packaging builds the image's wheel); these tests look at what the
package then imports, in fresh interpreters, as `invt-gateway run` would.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from gateway.build_backend import why_not_compiled
from gateway.compiled import (
    COMPILED_MODULES,
    PURE_PYTHON_ENV,
    built_from_these_sources,
    compiled_libraries,
    source_path,
)

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = ROOT / "gateway"

SHOW = """
import importlib, sys
import gateway
print(gateway.ENGINE_ROOM)
for name in sys.argv[1:]:
    print(importlib.import_module(name).__file__)
"""


def imported(folder: Path, *modules: str, pure: bool = False) -> tuple[str, list[str]]:
    """The engine room a fresh interpreter in `folder` says, and the files `modules` came from."""
    env = {key: value for key, value in os.environ.items() if key != PURE_PYTHON_ENV}
    if pure:
        env[PURE_PYTHON_ENV] = "1"
    env["PYTHONPATH"] = str(folder)
    shown = subprocess.run(
        [sys.executable, "-c", SHOW, *modules],
        capture_output=True,
        text=True,
        cwd=folder,
        env=env,
        timeout=60,
        check=True,
    ).stdout.splitlines()
    return shown[0], shown[1:]


def compiled_here() -> bool:
    """This checkout holds the engine room compiled from today's sources."""
    return built_from_these_sources(compiled_libraries())


def test_the_engine_room_is_compiled_where_this_machine_can_compile() -> None:
    """Where the build could compile (a C compiler, Python's headers), every module of the
    engine room is imported compiled, and the gateway says so; where it couldn't, from source."""
    engine_room, files = imported(ROOT, *COMPILED_MODULES)
    if os.environ.get(PURE_PYTHON_ENV):
        pytest.skip(f"{PURE_PYTHON_ENV} is set: this run is of the sources (.ci/run's second pass)")
    why_not = why_not_compiled()
    if why_not is not None:
        assert engine_room.startswith("Python ("), engine_room
        assert all(file.endswith(".py") for file in files), files
        return
    assert compiled_here(), (
        "this machine can compile the engine room, but this checkout holds no build of today's "
        "sources: `bash .ci/test` (or `pip install -e .`) builds it"
    )
    assert engine_room == "compiled by mypyc"
    assert [Path(file).suffix for file in files] == [".so"] * len(COMPILED_MODULES), files


def test_told_to_the_engine_room_runs_from_its_sources() -> None:
    engine_room, files = imported(ROOT, *COMPILED_MODULES, pure=True)
    assert engine_room == f"Python ({PURE_PYTHON_ENV} is set)"
    assert files == [str(source_path(module)) for module in COMPILED_MODULES]


def test_an_edited_source_runs_not_the_compiled_module_of_before(tmp_path: Path) -> None:
    """A compiled build, then one of its modules' sources edited: the edit is what runs, and
    every other module of the engine room runs from its source too (they call each other
    directly when compiled: never half of each)."""
    if not compiled_here():
        pytest.skip("this checkout is not compiled (no C compiler or Python headers at its build)")
    copy = tmp_path / "checkout"
    shutil.copytree(PACKAGE, copy / "gateway", ignore=shutil.ignore_patterns("__pycache__"))
    edited = copy / "gateway" / "bus" / "wakeup.py"
    edited.write_text(edited.read_text() + "\nEDITED_AFTER_THE_BUILD = True\n")

    engine_room, files = imported(copy, *COMPILED_MODULES)

    assert engine_room.startswith("Python (its compiled modules are of other sources"), engine_room
    assert files == [str(source_path(module, copy / "gateway")) for module in COMPILED_MODULES]
    check = subprocess.run(
        [sys.executable, "-c", "import gateway.bus.wakeup as w; print(w.EDITED_AFTER_THE_BUILD)"],
        capture_output=True,
        text=True,
        cwd=copy,
        env={**os.environ, "PYTHONPATH": str(copy)},
        timeout=60,
        check=True,
    )
    assert check.stdout == "True\n"
