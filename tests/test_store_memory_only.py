"""A store the gateway can't write from the start (a store file restored by root, a disk that
went read-only): the gateway serves SCADA and keeps events in memory, and says so: /health is
degraded naming storage.path, `invt-gateway healthcheck` exits 1 with the reason."""

from __future__ import annotations

import json
import urllib.request
from pathlib import Path
from typing import Any

import pytest

from gateway.store.database import EventDatabase
from tests.mqtt_setup import simulated_line
from tests.processes import gateway_process, run_cli
from tests.small_disk import read_only, small_disk
from tests.support import free_port


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
        restored = EventDatabase(str(store), 1 << 20, 86400.0, forwarding=True)
        restored.open()  # a store from a backup
        restored.close()
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
