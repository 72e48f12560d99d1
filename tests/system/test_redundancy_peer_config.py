"""`invt-gateway check-config --peer FILE`: the two boxes of a redundant pair (issue 48) read
each other's file: what differs is said, and the exit code fails on what both must share."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from tests.support.processes import run_cli
from tests.support.redundancy import box_config


def write(folder: Path, name: str, config: dict[str, Any]) -> str:
    path = folder / f"{name}.yaml"
    path.write_text(yaml.safe_dump(config))
    return str(path)


def pair(tmp_path: Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """Two boxes' files as a site writes them: each its own name, hold-off, adapter path and
    store; everything else alike."""
    a = box_config("/dev/serial/by-id/usb-a", tmp_path / "a", "active", 0, "gw-a")
    b = box_config("/dev/serial/by-id/usb-b", tmp_path / "b", "standby", 500, "gw-b")
    b["metrics"]["port"] = a["metrics"]["port"]
    b["modbus_tcp"]["host"] = "10.0.0.12"
    return a, b


def test_two_boxes_alike_but_for_their_own_keys_pass(tmp_path: Path) -> None:
    a, b = pair(tmp_path)
    done = run_cli(
        "check-config", "--config", write(tmp_path, "a", a), "--peer", write(tmp_path, "b", b)
    )
    assert done.returncode == 0, done.stdout + done.stderr
    assert "alike in everything both boxes must share" in done.stdout
    own = done.stdout.split("each box's own (may differ):")[1]
    assert "redundancy.box: gw-a here, gw-b on the peer" in own
    assert (
        "buses[line1].port: /dev/serial/by-id/usb-a here, /dev/serial/by-id/usb-b on the peer"
        in own
    )
    assert "modbus_tcp.host" in own


def test_a_poll_interval_and_the_base_topic_that_differ_fail(tmp_path: Path) -> None:
    a, b = pair(tmp_path)
    for config, topic in ((a, "plant"), (b, "plant2")):
        config["mqtt"] = {"host": "127.0.0.1", "port": 1883, "base_topic": topic}
    b["drives"][0]["poll"][0]["interval_ms"] = 500
    b["mqtt"]["password"] = "other"
    b["mqtt"]["username"] = "u"
    a["mqtt"]["password"] = "one"
    a["mqtt"]["username"] = "u"
    done = run_cli(
        "check-config", "--config", write(tmp_path, "a", a), "--peer", write(tmp_path, "b", b)
    )
    assert done.returncode == 1, done.stdout + done.stderr
    shared = done.stdout.split("differs in what both boxes must share:")[1]
    shared = shared.split("each box's own")[0]
    assert "drives[pump].poll[state].interval_ms: 200 here, 500 on the peer" in shared
    assert "mqtt.base_topic: plant here, plant2 on the peer" in shared
    assert "mqtt.password: (differs; a secret, not shown)" in shared
    assert "one" not in done.stdout
    assert "redundancy.box" not in shared
