"""Two real gateway processes on one simulated RS-485 pair (`simulate --masters 3`, real ptys):
an active and a standby, never two masters (issue 48).

What a site checks: the standby transmits nothing while the active serves; the active killed,
the standby asked to take over is on the line within the bound (the line's silence, derived
from the poll cycle: 1.0 s here, then the port's opening) with no collision; both asked to be
active (the link between the boxes cut), the second hears the first and stays off, and after
a few seconds says it must not hold the virtual address until the line is silent; a master
that talks without listening (the third port, played by the test) makes the active leave the
line at once, with no more than the frames already on the wire colliding.

Each box has its own configuration file, store and control socket, as two boxes would; the
coordinator (Keepalived) is played by the test through `invt-gateway role`.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import re
import signal
import sqlite3
import struct
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import serial

from gateway.modbus.rtu import build_frame
from gateway.redundancy.latch import LATCH_S
from tests.support import free_port
from tests.support.http import http_get
from tests.support.mosquitto import Mosquitto, retained_messages
from tests.support.processes import run_cli
from tests.support.redundancy import (
    POLL_MS,
    SILENCE_S,
    TAKEOVER_BOUND_S,
    Box,
    frames,
    pair_broker,
    start_pair,
)
from tests.support.redundancy import boxes as boxes  # the fixture
from tests.support.shared_line import SharedLine, shared_line


@pytest.fixture
def line() -> Iterator[SharedLine]:
    # The third master is the test's own: a misconfigured master that talks without listening.
    with shared_line(3, "--address", "1") as shared:
        yield shared


def test_the_standby_never_transmits_and_the_active_serves(
    line: SharedLine, boxes: list[Box], tmp_path: Path
) -> None:
    console_port = free_port()
    console = {"enabled": True, "port": console_port, "anonymous_view": True}
    active, standby = start_pair(boxes, line.paths, tmp_path, b={"console": console})
    time.sleep(2 * SILENCE_S)  # the standby listens all along
    # SCADA's values come from the active (the drive's state word), the standby says why not.
    assert active.read_state()[:2] == bytes([0x03, 0x02])
    assert standby.read_state() == bytes([0x83, 0x0A])
    status = standby.status()
    assert status["role"] == "standby"
    assert status["heard_requests"] > 5  # it hears the active's polls
    assert status["line_silent_s"] < SILENCE_S
    # The operator's console says which box this is, and its role.
    _, _, body = asyncio.run(http_get(console_port, "/api/overview"))
    shown = json.loads(body)["redundancy"]
    assert (shown["box"], shown["role"], shown["peer"]) == ("b", "standby", "the other box")
    stats = line.stats()
    assert stats["masters"][0]["frames"] > 10
    assert stats["masters"][1]["frames"] == 0
    assert stats["collisions"] == 0


def test_the_active_killed_the_standby_takes_over_within_the_bound(
    line: SharedLine, boxes: list[Box], tmp_path: Path
) -> None:
    old, new = start_pair(boxes, line.paths, tmp_path)
    time.sleep(0.5)
    old.gateway.process.send_signal(signal.SIGKILL)
    old.gateway.process.wait(5)
    killed = time.monotonic()
    new.notified("MASTER")  # Keepalived's VRRP: this box is MASTER now
    deadline = killed + TAKEOVER_BOUND_S
    while frames(line)[1] == 0:
        assert time.monotonic() < deadline, f"no request from the new active: {line.stats()}"
        time.sleep(0.02)
    first_request_s = time.monotonic() - killed
    status = new.wait_role("active", 1.0)
    # It listened first: the old active's last poll came at most one poll interval before the
    # kill, and the line had to be silent SILENCE_S after it.
    assert SILENCE_S - POLL_MS / 1000 < first_request_s < TAKEOVER_BOUND_S, first_request_s
    assert status["last_takeover_s"] < TAKEOVER_BOUND_S
    assert new.read_state()[:2] == bytes([0x03, 0x02])
    assert line.stats()["collisions"] == 0
    print(f"first request {first_request_s:.2f} s after the kill")


class RogueMaster:
    """A master that polls drive 1 every 100 ms without listening first (the third port)."""

    def __init__(self, path: str) -> None:
        self.port = serial.Serial(path, 19200, timeout=0)
        self.sent = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._talk, daemon=True)
        self._thread.start()

    def _talk(self) -> None:
        request = build_frame(1, struct.pack(">BHH", 3, 0x3000, 4))
        while not self._stop.wait(0.1):
            self.port.write(request)
            self.port.reset_input_buffer()
            self.sent += 1

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(2)
        self.port.close()


def test_both_asked_active_the_second_stays_off_and_a_talking_master_is_left_the_line(
    line: SharedLine, boxes: list[Box], tmp_path: Path
) -> None:
    boxes.append(first := Box("a", line.paths[0], tmp_path, "active"))
    first.wait_role("active", 5.0)
    # The link between the boxes cut: the second is asked to be active too (Keepalived's
    # MASTER on both sides). It hears the first's polls and stays off the line.
    boxes.append(second := Box("b", line.paths[1], tmp_path, "active", hold_off_ms=500))
    time.sleep(3 * SILENCE_S)
    assert second.status()["role"] == "listening"
    assert frames(line)[1] == 0
    assert line.stats()["collisions"] == 0

    # A master that talks without listening: the active hears a request it did not send.
    before = line.stats()
    rogue = RogueMaster(line.paths[2])
    try:
        status = first.wait_role("listening", 3.0)
        assert status["foreign_frames"] >= 1
        assert status["last_foreign"]["bus"] == "line1"
        assert first.health()["redundancy"]["last_foreign"]["bus"] == "line1"
        # The same count on the metric (as many frames as were heard by then: on a loaded
        # machine the rogue's next request may come before the active has left the line).
        metric = r"^invt_gateway_redundancy_foreign_frames_total (\S+)$"
        counted = re.search(metric, first.metrics(), re.M)
        assert counted is not None
        assert float(counted[1]) >= status["foreign_frames"] >= 1
        left_at = frames(line)[0]
        time.sleep(1.0)
        # Off the line while the other master talks: not one frame more, from either box.
        assert frames(line)[0] == left_at
        assert frames(line)[1] == 0
        assert second.status()["role"] == "listening"
    finally:
        rogue.stop()
    collided = line.stats()["collisions"] - before["collisions"]
    # Only what was on the wire as the first foreign request was heard: the active's request
    # then (and the drive's reply to it).
    assert collided <= 2, line.stats()
    assert "another master is on the line" in first.gateway.log.text
    # Leaving the line is no lost port: no drive said offline, no port event for it.
    assert "port lost" not in first.gateway.log.text

    # The talking master gone, the line is silent: one box takes it, the other stays off.
    deadline = time.monotonic() + 10
    while True:
        roles = sorted(box.status()["role"] for box in (first, second))
        if roles == ["active", "listening"]:
            break
        assert time.monotonic() < deadline, roles
        time.sleep(0.1)
    # The coordinator settles it: the listening one told standby is standby.
    listening = next(box for box in (first, second) if box.status()["role"] == "listening")
    assert listening.ask("standby").startswith("ok: standby")
    listening.wait_role("standby", 2.0)


def test_asked_active_while_another_master_polls_it_gives_the_address_up_until_silence(
    line: SharedLine, boxes: list[Box], tmp_path: Path
) -> None:
    """A cut between the boxes as a gateway sees it: asked to be active (its Keepalived MASTER)
    while the other polls. After `LATCH_S` hearing it, its fault file says 1 (Keepalived drops
    the address), `role status` and /health say why, the log and an event; asked standby (its
    notify on FAULT) it stays so while the other polls; the other gone, the line silent
    `silence_ms`, the file says 0 again, and asked active it takes the line."""
    boxes.append(first := Box("a", line.paths[0], tmp_path, "active"))
    first.wait_role("active", 5.0)
    boxes.append(second := Box("b", line.paths[1], tmp_path, "active", hold_off_ms=500))
    asked = time.monotonic()
    assert second.status()["role"] == "listening"
    assert not second.says_unfit()
    while not second.says_unfit():
        assert time.monotonic() - asked < LATCH_S + 1.0
        time.sleep(0.05)
    status = second.status()
    assert status["fit"] is False
    assert "another master heard while this box was asked to be active" in status["unfit"]
    assert status["another_master_heard_s"] >= LATCH_S
    assert not second.check_fails()  # the fault file tells Keepalived: the track script passes
    assert second.health()["status"] == "degraded"
    assert "invt_gateway_redundancy_fit 0.0" in second.metrics()
    assert "gives the virtual address up" in second.gateway.log.text

    # Its Keepalived FAULT: standby. Still hearing the other master, it stays unfit.
    second.notified("FAULT")
    time.sleep(2 * SILENCE_S)
    assert second.says_unfit()
    assert second.status()["role"] == "standby"

    # The other gone: the line silent `silence_ms`, fit again; asked active, it takes the line.
    first.gateway.process.send_signal(signal.SIGKILL)
    first.gateway.process.wait(5)
    killed = time.monotonic()
    while second.says_unfit():
        assert time.monotonic() - killed < SILENCE_S + 1.0
        time.sleep(0.05)
    cleared_s = time.monotonic() - killed
    assert cleared_s > SILENCE_S - 0.3  # the other's last poll came up to one poll before
    assert "no other master heard for 1.0 s" in second.gateway.log.text
    assert second.status()["fit"] is True
    assert "invt_gateway_redundancy_fit 1.0" in second.metrics()
    assert frames(line)[1] == 0
    second.notified("MASTER")
    second.wait_role("active", TAKEOVER_BOUND_S)
    assert line.stats()["collisions"] == 0
    store = tmp_path / "b" / "events.db"
    deadline = time.monotonic() + 5
    while (said := events_in(store, "another_master_%")) != [
        "another_master_heard",
        "another_master_gone",
    ]:
        assert time.monotonic() < deadline, said
        time.sleep(0.1)


def events_in(store: Path, kinds: str) -> list[str]:
    """The types of the store's events like `kinds` (SQL's LIKE), oldest first."""
    with contextlib.closing(sqlite3.connect(f"file:{store}?mode=ro", uri=True)) as db:
        query = "SELECT type FROM events WHERE type LIKE ? ORDER BY id"
        return [kind for (kind,) in db.execute(query, (kinds,)).fetchall()]


def test_on_mqtt_a_standby_publishes_only_its_role(
    line: SharedLine, boxes: list[Box], tmp_path: Path, mosquitto: Mosquitto
) -> None:
    base, _, broker = pair_broker(mosquitto)
    boxes.append(standby := Box("b", line.paths[1], tmp_path, "standby", mqtt=broker))
    time.sleep(1.0)
    # Alone on the line, a standby: its role and health, and what it runs of the configuration
    # both boxes share (digests), and nothing of the drives.
    retained = asyncio.run(retained_messages(mosquitto, f"{base}/#"))
    own = f"{base}/bridge/redundancy/b"
    assert sorted(retained) == [own, f"{own}/config"]
    digests = json.loads(retained[f"{own}/config"])["keys"]
    assert "drives[pump].poll[state].interval_ms" in digests
    assert "redundancy.box" not in digests  # each box's own: not compared
    role = json.loads(retained[f"{base}/bridge/redundancy/b"])
    assert (role["box"], role["role"], role["health"]) == ("b", "standby", "ok")
    assert standby.health()["status"] == "ok"  # closed buses on purpose: not degraded

    boxes.append(active := Box("a", line.paths[0], tmp_path, "active", mqtt=broker))
    active.wait_role("active", 5.0)
    deadline = time.monotonic() + 10
    while True:
        retained = asyncio.run(retained_messages(mosquitto, f"{base}/#"))
        if f"{base}/pump" in retained and f"{base}/bridge/redundancy/a" in retained:
            break
        assert time.monotonic() < deadline, sorted(retained)
        time.sleep(0.2)
    assert json.loads(retained[f"{base}/bridge/redundancy/a"])["role"] == "active"
    assert json.loads(retained[f"{base}/bridge/redundancy/b"])["role"] == "standby"
    assert json.loads(retained[f"{base}/bridge/state"])["state"] == "online"
    assert line.stats()["masters"][1]["frames"] == 0


def test_the_standby_s_death_changes_nothing(
    line: SharedLine, boxes: list[Box], tmp_path: Path
) -> None:
    active, standby = start_pair(boxes, line.paths, tmp_path)
    standby.gateway.process.send_signal(signal.SIGKILL)
    standby.gateway.process.wait(5)
    before = frames(line)[0]
    time.sleep(1.0)
    assert frames(line)[0] >= before + 3  # polled on, five times a second
    status = active.status()
    assert (status["role"], status["takeovers"], status["foreign_frames"]) == ("active", 1, 0)
    assert line.stats()["collisions"] == 0


def test_a_flapping_active_never_makes_two_masters(
    line: SharedLine, boxes: list[Box], tmp_path: Path
) -> None:
    """Whichever box is active is killed (SIGKILL) and started again at once, ten times within a
    minute: each comes back asked to be active (`role: active` in its file, as a box whose
    Keepalived says MASTER at once would), listens, hears the other that took over meanwhile,
    and stays off: not one frame from it while the other is the master, 0 collisions."""
    boxes.append(Box("a", line.paths[0], tmp_path, "active"))
    boxes[0].wait_role("active", 5.0)
    boxes.append(Box("b", line.paths[1], tmp_path, "active", hold_off_ms=300))
    boxes[1].wait_role("listening", 2.0)
    started = time.monotonic()
    for _ in range(10):
        roles = [box.status()["role"] for box in boxes]
        assert sorted(roles) == ["active", "listening"], roles
        dying = roles.index("active")
        name, path = boxes[dying].name, line.paths[dying]
        boxes[dying].gateway.process.send_signal(signal.SIGKILL)
        boxes[dying].gateway.process.wait(5)
        boxes[dying].stop()
        boxes[dying] = Box(name, path, tmp_path, "active", hold_off_ms=300 * dying)
        boxes[1 - dying].wait_role("active", 5.0)
        boxes[dying].wait_role("listening", 2.0)
        # While the other is the master, the one that came back transmits nothing.
        off_at = frames(line)[dying]
        time.sleep(0.5)
        assert frames(line)[dying] == off_at
        assert line.stats()["collisions"] == 0
    flapped_s = time.monotonic() - started
    print(f"10 kills and restarts in {flapped_s:.1f} s")
    assert flapped_s < 60
    stats = line.stats()
    assert stats["collisions"] == 0
    assert all(master["frames"] > 0 for master in stats["masters"][:2])
    assert all(master["collisions"] == 0 for master in stats["masters"])


def test_a_reload_reopens_the_active_s_line_watched_and_waits_on_a_standby(
    line: SharedLine, boxes: list[Box], tmp_path: Path
) -> None:
    active, standby = start_pair(boxes, line.paths, tmp_path)
    for box in (active, standby):  # a longer response timeout: the bus is reopened with it
        path = Path(box.config)
        path.write_text(path.read_text().replace("timeout_ms: 100", "timeout_ms: 120"))
    skipped = run_cli("reload", "--config", standby.config)
    assert skipped.returncode == 1
    assert "skipped: this gateway is standby: restart it to apply the file" in skipped.stderr
    applied = run_cli("reload", "--config", active.config)
    assert applied.returncode == 0, applied.stderr
    assert "buses reopened: line1" in applied.stdout
    time.sleep(0.5)
    assert frames(line)[1] == 0
    # The reopened bus is watched as the one before: another master heard, it leaves the line.
    rogue = RogueMaster(line.paths[2])
    try:
        active.wait_role("listening", 3.0)
    finally:
        rogue.stop()


def test_a_standby_that_can_t_hear_its_line_says_so(boxes: list[Box], tmp_path: Path) -> None:
    boxes.append(standby := Box("b", str(tmp_path / "no-adapter"), tmp_path, "standby"))
    time.sleep(0.5)
    assert standby.status()["deaf"] == ["line1"]
    health = standby.health()
    assert health["status"] == "degraded"
    assert health["redundancy"]["deaf"] == ["line1"]
    assert "can't listen to the line" in standby.gateway.log.text
