"""The store's backup and restore recipe on the Events page, run as written (paths moved into a
temporary folder) against the store of a running gateway: the copy is whole while the gateway
writes, and a gateway started on the restored copy finds its events waiting.

The commands are read from the page, so the recipe can't drift from what is tested. The Docker
lines run the same Python inside the container (`docker exec`), so the Python line is what is
run here; `docker` itself is not (no daemon on a test machine).
"""

from __future__ import annotations

import re
import shlex
import sqlite3
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from tests.support import free_port
from tests.support.processes import gateway_process
from tests.support.site import DOCS

STATE = "/var/lib/invt-gateway"
BACKUP = "/srv/backup"
STORE = "events-invt-gateway.db"
"""The file the page's recipe names: the default of the default gateway_id."""
WAIT_S = 20.0


def recipe() -> list[str]:
    """The lines of the page's backup and restore blocks, comments left out."""
    text = (DOCS / "pages" / "events.md").read_text(encoding="utf-8")
    section = text.split("## Backing up the store", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```sh\n(.*?)```", section, re.DOTALL)
    assert len(blocks) == 2, "a backup block and a restore block"
    joined = "\n".join(blocks).replace("\\\n", "")
    return [line.strip() for line in joined.splitlines() if line.strip()[:1] not in ("#", "")]


def gateway_config(state: Path, tmp_path: Path) -> dict[str, Any]:
    """A gateway whose line is missing and whose broker isn't there: its drives go offline and
    the events wait in the store, written while the backup runs."""
    return {
        "gateway_id": "backup-test",
        "modbus_tcp": {"host": "127.0.0.1", "port": 0},
        "buses": [{"name": "line1", "port": str(tmp_path / "no-such-tty"), "timeout_ms": 20}],
        "drives": [
            {"name": "pump1", "bus": "line1", "address": 1},
            {"name": "fan2", "bus": "line1", "address": 2},
        ],
        "mqtt": {"host": "127.0.0.1", "port": free_port(), "reconnect_max_s": 1},
        "storage": {"path": str(state / STORE)},
    }


def stored_events(path: Path) -> int:
    """The events of a store the gateway is still making: 0 before its file and its tables."""
    try:
        return count_events(path) if path.exists() else 0
    except sqlite3.OperationalError:  # the file made, the schema not yet
        return 0


def count_events(path: Path) -> int:
    with sqlite3.connect(f"file:{path}?mode=ro", uri=True) as db:
        return int(db.execute("select count(*) from events").fetchone()[0])


def test_the_backup_recipe_copies_a_live_store_and_the_restore_brings_it_back(
    tmp_path: Path,
) -> None:
    state, backup = tmp_path / "state", tmp_path / "backup"
    state.mkdir()
    backup.mkdir()
    lines = [line.replace(STATE, str(state)).replace(BACKUP, str(backup)) for line in recipe()]
    python_lines = [line for line in lines if line.startswith("python3 -c ")]
    in_container = [line for line in lines if line.startswith("docker exec invt-gateway python")]
    assert len(python_lines) == 1
    assert len(in_container) == 1
    assert not [line for line in lines if "docker run" in line and "alpine" in line]
    assert not [line for line in lines if "apk add" in line or "apt-get" in line]

    with gateway_process(gateway_config(state, tmp_path), tmp_path) as gateway:
        deadline = time.monotonic() + WAIT_S
        while stored_events(state / STORE) < 1:
            assert time.monotonic() < deadline, gateway.log.text
            time.sleep(0.2)
        seen = count_events(state / STORE)
        # The host's line, then the container's (its paths under the same folder), while the
        # gateway keeps its database open and writes.
        for command in (python_lines[0], in_container[0].removeprefix("docker exec invt-gateway ")):
            argv = shlex.split(command)
            argv[0] = sys.executable
            subprocess.run(argv, check=True, timeout=30)
        assert gateway.process.poll() is None, gateway.log.text

    copies = [backup / "invt-gateway-events.db", state / "events-backup.db"]
    for copy in copies:
        with sqlite3.connect(copy) as db:
            assert db.execute("pragma integrity_check").fetchone() == ("ok",)
        assert count_events(copy) >= seen

    # The restore, as the systemd block says (its state directory is our state folder).
    restore = [line for line in lines if line.startswith(("cp ", "rm -f "))]
    assert len(restore) == 2
    (state / STORE).unlink()
    for command in restore:
        subprocess.run(["sh", "-c", command], check=True, timeout=30)
    assert not (state / f"{STORE}-wal").exists()
    restored = count_events(state / STORE)
    assert restored >= seen
    with gateway_process(gateway_config(state, tmp_path), tmp_path) as gateway:
        gateway.log.wait_for(f"store {state / STORE}: ", WAIT_S)
        assert "events wait for the broker" in gateway.log.text
