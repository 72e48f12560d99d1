"""The build's choice to compile the engine room, or not and why (gateway/build_backend.py):
what the install says, and what decides whether the build asks pip for mypy at all (the builds
themselves: test_ops_packaging's wheel, and .venv's editable install)."""

from __future__ import annotations

import platform

import pytest

from gateway import build_backend
from gateway.compiled import PURE_PYTHON_ENV


def test_told_not_to_the_build_does_not_compile(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(PURE_PYTHON_ENV, "1")
    assert build_backend.why_not_compiled() == f"{PURE_PYTHON_ENV} is set"


def test_without_a_c_compiler_the_build_is_python_and_says_which_compiler(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.delenv(PURE_PYTHON_ENV, raising=False)
    monkeypatch.setenv("CC", "no-such-cc -pthread")
    why_not = build_backend.why_not_compiled()
    if why_not is not None and "no C compiler" not in why_not:
        pytest.skip(f"this machine can't compile for another reason: {why_not}")
    assert why_not == "no C compiler (no-such-cc; Debian: apt install gcc)"


def test_on_32_bit_arm_the_build_is_python(monkeypatch: pytest.MonkeyPatch) -> None:
    """mypy and its C parts have no wheel there: asking pip for them would fail the install."""
    monkeypatch.delenv(PURE_PYTHON_ENV, raising=False)
    monkeypatch.setattr(platform, "machine", lambda: "armv7l")
    assert build_backend.why_not_compiled() == (
        "mypyc comes as a wheel for 64-bit x86 and ARM, not armv7l with this Python"
    )
