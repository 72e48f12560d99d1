"""The package's build backend (pyproject.toml's `build-backend`): setuptools, which compiles the
engine room (gateway/compiled.py's modules) with mypyc where this machine can, and builds the
same package as Python where it can't.

It can when a C compiler and this Python's headers are here (Debian: gcc and python3-dev; the
official Python images have the headers), on a 64-bit x86 or ARM Python (where mypy comes as
a wheel), and `INVT_GATEWAY_PURE_PYTHON` is not set. Then the build asks for mypy (mypyc comes
with it) and the package's own dependencies (mypy type-checks the modules against them, with
pyproject.toml's configuration, before compiling), and names the shared library for the
sources' digest, which the package checks when imported. A compiler that fails leaves a build
in Python, said on the build's output, never a failed install: the gateway is the same either
way, only slower.
"""

from __future__ import annotations

import os
import platform
import shlex
import shutil
import struct
import sys
import sysconfig
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from setuptools import build_meta, setup

from gateway.compiled import (
    COMPILED_MODULES,
    PACKAGE,
    PURE_PYTHON_ENV,
    library_group,
    source_digest,
    source_path,
)

MYPY = "mypy==2.4.1"
"""The mypy (and mypyc) that compiles: pinned, so a build compiles as the tested one did."""
TYPE_STUBS = ("types-pyserial", "types-PyYAML", "types-protobuf")
"""The stubs the strict type check of the compiled modules' imports needs (the test extras')."""
COMPILING_COMMANDS = {"bdist_wheel", "editable_wheel", "build_ext"}
"""What setuptools is asked to do when it builds code (not when it asks for metadata)."""
COMPILING_MACHINES = {"x86_64", "amd64", "aarch64", "arm64"}
"""Where mypy and its own C parts (librt, ast-serialize) come as wheels, with a 64-bit Python:
elsewhere (32-bit ARM) pip would have to build them, Rust included, and the install fail."""


def why_not_compiled() -> str | None:
    """None when this machine can compile the engine room, else why not."""
    if os.environ.get(PURE_PYTHON_ENV):
        return f"{PURE_PYTHON_ENV} is set"
    machine = platform.machine()
    if machine.lower() not in COMPILING_MACHINES or struct.calcsize("P") != 8:
        return f"mypyc comes as a wheel for 64-bit x86 and ARM, not {machine} with this Python"
    headers = Path(sysconfig.get_path("include")) / "Python.h"
    if not headers.is_file():
        return f"no {headers} (Debian: apt install python3-dev)"
    compiler = shlex.split(os.environ.get("CC") or str(sysconfig.get_config_var("CC") or "cc"))[:1]
    if not compiler or shutil.which(compiler[0]) is None:
        return f"no C compiler ({' '.join(compiler) or 'cc'}; Debian: apt install gcc)"
    return None


def _say(message: str) -> None:
    print(f"invt-gateway build: {message}", file=sys.stderr, flush=True)


def _dependencies() -> list[str]:
    with Path("pyproject.toml").open("rb") as file:
        project: dict[str, Any] = tomllib.load(file)["project"]
    return list(project["dependencies"])


def _engine_room_extensions() -> list[Any]:
    """mypyc's extension modules for the engine room, or none (and why) if it can't compile."""
    why_not = why_not_compiled()
    if why_not is not None:
        _say(f"the engine room stays Python: {why_not}")
        return []
    try:
        from mypyc.build import mypycify
    except ImportError:  # a build without isolation, in an environment without mypy
        _say(f"the engine room stays Python: mypyc is not installed ({MYPY})")
        return []
    root = PACKAGE.parent  # the project's folder, where the build runs
    sources = [str(source_path(module).relative_to(root)) for module in COMPILED_MODULES]
    _say(f"compiling the engine room with mypyc ({len(sources)} modules, a minute or two)")
    try:
        return list(mypycify(sources, group_name=library_group(source_digest())))
    except (Exception, SystemExit) as failure:  # mypy's errors end in SystemExit
        _say(f"the engine room stays Python: mypyc failed ({failure!r})")
        return []


class _Backend(build_meta._BuildMetaBackend):
    """setuptools' own backend (a private class: pyproject.toml pins setuptools' range), with the
    engine room's extension modules given to setup() when code is built."""

    def run_setup(self, setup_script: str = "setup.py") -> None:
        if COMPILING_COMMANDS.isdisjoint(sys.argv[1:]):
            super().run_setup(setup_script)
            return
        extensions = _engine_room_extensions()
        if extensions:
            try:
                setup(ext_modules=extensions)
                return
            except (Exception, SystemExit) as failure:  # setuptools ends a failed command so
                _say(f"the engine room stays Python: compiling it failed ({failure})")
        setup()

    def get_requires_for_build_wheel(
        self, config_settings: Mapping[str, str | list[str] | None] | None = None
    ) -> list[str]:
        requirements: list[str] = super().get_requires_for_build_wheel(config_settings)
        if why_not_compiled() is None:
            requirements += [MYPY, *TYPE_STUBS, *_dependencies()]
        return requirements


_BACKEND = _Backend()
get_requires_for_build_wheel = _BACKEND.get_requires_for_build_wheel
get_requires_for_build_sdist = _BACKEND.get_requires_for_build_sdist
get_requires_for_build_editable = _BACKEND.get_requires_for_build_editable
prepare_metadata_for_build_wheel = _BACKEND.prepare_metadata_for_build_wheel
prepare_metadata_for_build_editable = _BACKEND.prepare_metadata_for_build_editable
build_wheel = _BACKEND.build_wheel
build_sdist = _BACKEND.build_sdist
build_editable = _BACKEND.build_editable
