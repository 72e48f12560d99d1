"""Figures the tests measured (recovery times, faults survived), shown after the run.

A test records one with `record_property("figure:<what>", text)`; they also land in a JUnit XML
report (`--junitxml`) as properties, so CI can keep them.
"""

from __future__ import annotations

import pytest

from gateway.config import ENV_STATE_DIRECTORY

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


@pytest.fixture(autouse=True)
def own_state_directory(
    tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Each test its own store (`storage.path` defaults to $STATE_DIRECTORY/events.db), for the
    gateways it runs in-process and the ones it starts as subprocesses alike: never the machine's
    /var/lib/invt-gateway, never what another test left."""
    monkeypatch.setenv(ENV_STATE_DIRECTORY, str(tmp_path_factory.mktemp("state")))
