"""A store the gateway can't write from the start (a store file restored by root, a disk that
went read-only): the gateway serves SCADA and keeps events in memory, and says so: /health is
degraded naming storage.path, `invt-gateway healthcheck` exits 1 with the reason, the console
shows a banner."""

from __future__ import annotations

import asyncio
import json
import urllib.request
from pathlib import Path
from typing import Any

import pytest

from gateway.config import StorageConfig
from gateway.instruments.simulator import SimulatedLine
from gateway.store.database import EventDatabase
from tests.support import free_port, present, running_gateway
from tests.support.browser import CHROMEDRIVER, CHROMIUM, Browser, showing
from tests.support.console_support import console_config
from tests.support.mqtt_setup import simulated_line
from tests.support.processes import gateway_process, run_cli
from tests.support.small_disk import read_only, small_disk


def restored_store(store: Path) -> None:
    """A store from a backup, as `cp` by root leaves it."""
    restored = EventDatabase(str(store), 1 << 20, 86400.0, forwarding=True)
    restored.open()
    restored.close()


def file_config(line_path: str, store: Path) -> dict[str, Any]:
    return {
        "gateway_id": "restored",
        "modbus_tcp": {"host": "127.0.0.1", "port": free_port()},
        "buses": [{"name": "line1", "port": line_path, "baudrate": 115200, "parity": "E"}],
        "drives": [{"bus": "line1", "name": "pump1", "address": 1, "model": "gd350"}],
        "storage": {"path": str(store)},
        "metrics": {"enabled": True, "host": "127.0.0.1", "port": free_port()},
    }


def health(config: dict[str, Any]) -> dict[str, Any]:
    url = f"http://127.0.0.1:{config['metrics']['port']}/health"
    with urllib.request.urlopen(url, timeout=5) as response:
        report: dict[str, Any] = json.loads(response.read())
    return report


@pytest.mark.parametrize("what", ["the file", "the disk"])
def test_a_store_that_cannot_be_written_is_degraded_and_says_why(tmp_path: Path, what: str) -> None:
    with small_disk(tmp_path / "disk") as disk, simulated_line((1,)) as line:
        store = disk / "events.db"
        restored_store(store)
        config = file_config(line.path, store)
        with (
            read_only(store if what == "the file" else disk),
            gateway_process(config, tmp_path) as gateway,
        ):
            gateway.wait_ready()
            report = health(config)
            check = run_cli("healthcheck", "--config", str(gateway.config_file))
    assert report["status"] == "degraded"
    assert report["buses"]["line1"]["drives_offline"] == []  # the store alone
    assert report["store"]["state"] == "memory_only"
    assert "storage.path" in report["store"]["reason"]
    assert str(store) in report["store"]["reason"]
    assert check.returncode == 1, check.stdout + check.stderr
    assert json.loads(check.stdout)["status"] == "degraded"
    assert check.stderr.startswith("store: storage.path")
    assert str(store) in check.stderr


@pytest.mark.skipif(CHROMIUM is None or CHROMEDRIVER is None, reason="no chromium here")
async def test_the_console_shows_a_banner_while_events_are_in_memory_only(
    line: SimulatedLine, tmp_path: Path
) -> None:
    store = tmp_path / "events.db"
    restored_store(store)
    config = console_config(line.path, anonymous_view=True)
    config = config.model_copy(update={"storage": StorageConfig(path=str(store))})
    with read_only(store):
        async with running_gateway(config) as app:
            browser = await asyncio.to_thread(
                Browser, f"http://127.0.0.1:{present(app.console).port}"
            )
            try:
                await browser.open("/")
                await browser.wait(showing("#store-banner", "Events are not kept on disk"))
                banner = await browser.text("#store-banner")
            finally:
                await asyncio.to_thread(browser.close)
    assert "storage.path" in banner
    assert str(store) in banner
