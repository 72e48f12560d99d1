"""Figures the tests measured (recovery times, faults survived), shown after the run.

A test records one with `record_property("figure:<what>", text)`; they also land in a JUnit XML
report (`--junitxml`) as properties, so CI can keep them.
"""

from __future__ import annotations

import pytest

FIGURE = "figure:"


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    figures = [
        (name.removeprefix(FIGURE), value)
        for report in terminalreporter.stats.get("passed", [])
        if report.when == "call"
        for name, value in report.user_properties
        if isinstance(name, str) and name.startswith(FIGURE)
    ]
    if figures:
        terminalreporter.section("figures")
        for name, value in figures:
            terminalreporter.write_line(f"{name}: {value}")
