"""The log as the service writes it: `caplog`'s records through the same `RepeatFilter` that
`gateway.logs.setup_logging` puts on the service's handler, at the service's default level."""

from __future__ import annotations

import logging

import pytest

from gateway.logs import RepeatFilter


def service_log(caplog: pytest.LogCaptureFixture) -> pytest.LogCaptureFixture:
    """`caplog`, from now on seeing only what the service's log would show (info and up, a
    hostile client's repeats once a minute)."""
    caplog.set_level(logging.INFO)
    caplog.handler.addFilter(RepeatFilter())
    return caplog


def lines(caplog: pytest.LogCaptureFixture, name: str) -> list[str]:
    """The lines logged by `name` (a logger, and the loggers under it)."""
    return [
        f"{r.levelname} {r.getMessage()}"
        for r in caplog.records
        if r.name == name or r.name.startswith(f"{name}.")
    ]
