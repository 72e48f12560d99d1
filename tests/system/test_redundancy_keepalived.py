"""Two gateway boxes for real on this machine: each a network namespace with its own address and
a real Keepalived (VRRP, unicast between the boxes, the shipped notify script), both wired to one
simulated RS-485 pair (`simulate --masters 2`); SCADA on the switch reads through the virtual
address (issue 48). Needs root (skipped otherwise).

- the MASTER's gateway serves the line and the virtual address; the BACKUP's transmits nothing;
- the active box dies (its Keepalived and its gateway SIGKILLed, its network gone): the virtual
  address moves, the other box takes the line, SCADA's next connection is served, 0 collisions;
- the active box's network gone while both run (its interface down on the box, or its carrier
  lost at the switch: a pulled cable): its Keepalived sees its interface down and goes FAULT
  (its gateway asked standby, off the line at once), the other box is MASTER after 3 adverts
  missed and takes the line; the cable back, the old box is BACKUP (`nopreempt`) and never
  transmits;
- the link between the boxes cut while both run: both are VRRP MASTER, both asked `active`;
  the second hears the first's polls and stays off the line: 0 frames from it, 0 collisions;
  it gives the virtual address up (its fault file: FAULT) and the first's gratuitous ARPs
  (`garp_master_refresh`) draw SCADA back to it, served through the cut; the active box then
  dying, once the link is back or in the cut, the line's silence clears the latch and the other
  box takes the line;
- the active box's USB adapter unplugged: its gateway's fault file says 1 a second later
  (Keepalived's track_file), its Keepalived goes FAULT at once and sends an advert of priority 0,
  the virtual address moves, and the other box's first request is on the line within 3 s of the
  unplug.

VRRP's timing is the shipped file's (config/keepalived.conf: VRRPv3, adverts every 0.5 s): the
BACKUP declares a dead MASTER gone after 3 adverts missed and its skew, about 1.8 s.
"""

from __future__ import annotations

import contextlib
import os
import re
import signal
import struct
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

import pytest

from gateway.instruments.die_with_parent import die_with_parent
from gateway.redundancy.latch import LATCH_S
from tests.support.netns import VIRTUAL, BoxNet, PlantNetwork, can_make_namespaces, plant_network
from tests.support.processes import ROOT, LineCollector, end, entry_point
from tests.support.redundancy import NOTIFY, Box, frames
from tests.support.shared_line import SharedLine, shared_line

pytestmark = pytest.mark.skipif(
    can_make_namespaces() is not None, reason=str(can_make_namespaces())
)

MODBUS_PORT = 5020
SHIPPED = (ROOT / "config" / "keepalived.conf").read_text()
TAKEOVER_BOUND_S = 3.0
"""From the kill, the cut, or the unplug, to the new active's first request on the line: issue
48's bound. The kill, and the cut (the cut box's gateway leaves the line at once, on its FAULT):
VRRP's ~1.8 s, the notify script's start, the port's opening. The unplug: the
second without a port (`PORTLESS_S`), the priority-0 advert and the other box's skew (~0.3 s),
the notify script; the line's silence (1.5 s here) is over by then."""


SERVED = bytes([0x03, 0x02])
"""SCADA's read answered with the drive's value (function 03H, 2 bytes)."""
REFUSED = bytes([0x83, 0x0A])
"""Exception 0AH: a box that isn't the line's master (standby, listening)."""
SERVED_IN_CUT_S = 8.0
"""From the second box MASTER in a cut between the boxes to SCADA served for good: the latch's
`LATCH_S` (3 s, counted from its notify's `role active`, ~0.2 s), the role machine's look (0.25
s), its Keepalived FAULT on the fault file (at once), the active box's next gratuitous ARP
(`garp_master_refresh`: 2 s), and a read sent to the old address meanwhile (no answer within
its 2 s)."""
TAKEOVER_AFTER_CUT_S = 5.0
"""The active killed after the cut, while the other box is latched: the line's silence that
clears the latch (1 s here), then VRRP's BACKUP to MASTER (~1.8 s), the notify script."""


def shipped(key: str) -> str:
    """A setting's value in config/keepalived.conf: the test runs what a site installs."""
    found = re.search(rf"^\s*{key}\s+(\S+)", SHIPPED, re.MULTILINE)
    assert found is not None, key
    return found.group(1)


class Keepalived:
    """Keepalived in one box's namespace, as a box runs it (VRRP only, in the foreground)."""

    def __init__(self, net: BoxNet, peer: BoxNet, priority: int, box: Box, folder: Path) -> None:
        folder.mkdir(exist_ok=True)
        self.folder = folder
        notify = folder / "notify.sh"
        # Keepalived hands its scripts no environment of ours: the shipped script, told where
        # this box's gateway and file are.
        notify.write_text(
            "#!/bin/sh\n"
            "PATH=/usr/sbin:/usr/bin:/sbin:/bin\n"
            f'CONFIG={box.config} GATEWAY={entry_point()} UNIT=none exec {NOTIFY} "$@"\n'
        )
        notify.chmod(0o755)
        conf = folder / "keepalived.conf"
        conf.write_text(vrrp_config(net, peer, priority, notify, f"{notify} check", box))
        command = [
            "keepalived", "--dont-fork", "--log-console", "--log-detail", "--vrrp",
            "--use-file", str(conf), "--pid", str(folder / "k.pid"),
            "--vrrp_pid", str(folder / "v.pid"),
        ]  # fmt: skip
        self.process = subprocess.Popen(
            net.exec(*command),
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            preexec_fn=die_with_parent(),
        )
        self.log = LineCollector(self.process.stdout)

    def kill(self) -> None:
        """SIGKILL, its VRRP process first (it would go on advertising a while on its own)."""
        with contextlib.suppress(OSError, ValueError):
            os.kill(int((self.folder / "v.pid").read_text()), signal.SIGKILL)
        with contextlib.suppress(ProcessLookupError):
            os.kill(self.process.pid, signal.SIGKILL)
        self.process.wait(5)

    def stop(self) -> None:
        end(self.process, self.log)


def vrrp_config(
    net: BoxNet, peer: BoxNet, priority: int, notify: Path, check: str, box: Box
) -> str:
    """config/keepalived.conf's instance for this box, its timing and checks the shipped ones,
    unicast to the peer, the scripts and the fault file this box's."""
    assert "notify " in SHIPPED
    assert "vrrp_script invt_gateway_alive" in SHIPPED
    assert "track_file invt_gateway_fault" in SHIPPED
    return f"""global_defs {{
    router_id {net.namespace}
    vrrp_version {shipped("vrrp_version")}
    script_user root
}}
vrrp_script invt_gateway_alive {{
    script "{check}"
    interval {shipped("interval")}
    timeout {shipped("timeout")}
    fall {shipped("fall")}
    rise {shipped("rise")}
}}
track_file invt_gateway_fault {{
    file "{box.fault_file}"
    weight {shipped("weight")}
    init_file 0
}}
vrrp_instance invt_gateway {{
    state BACKUP
    nopreempt
    interface eth0
    virtual_router_id 48
    priority {priority}
    advert_int {shipped("advert_int")}
    garp_master_refresh {shipped("garp_master_refresh")}
    unicast_src_ip {net.address}
    unicast_peer {{
        {peer.address}
    }}
    virtual_ipaddress {{
        {VIRTUAL}/24 dev eth0
    }}
    track_script {{
        invt_gateway_alive
    }}
    track_file {{
        invt_gateway_fault
    }}
    notify "{notify}"
}}
"""


def scada_read(net: PlantNetwork) -> bytes:
    """State word 1 of unit 1 read through the virtual address, from SCADA's place on the
    switch: the reply's PDU (b"" when nobody answered)."""
    request = struct.pack(">HHHBBHH", 7, 0, 6, 1, 3, 0x2100, 1)
    script = (
        "import socket,sys\n"
        f"s=socket.create_connection(({VIRTUAL!r},{MODBUS_PORT}),timeout=2)\n"
        f"s.sendall(bytes.fromhex({request.hex()!r}))\n"
        "sys.stdout.write(s.recv(256)[7:].hex())\n"
    )
    done = subprocess.run(
        net.on_lan("python3", "-c", script), capture_output=True, text=True, timeout=10, check=False
    )
    return bytes.fromhex(done.stdout.strip()) if done.returncode == 0 else b""


def holds_virtual(net: BoxNet) -> bool:
    return f"{VIRTUAL}/24" in net.addresses()


@dataclass(frozen=True)
class Side:
    """One box as the test sees it: its gateway, its network, its Keepalived, and its number
    among the line's masters (from 0)."""

    index: int
    box: Box
    net: BoxNet
    keepalived: Keepalived


@dataclass
class Site:
    """The line, the network, the two boxes (a: priority 150, b: 100, hold-off 500 ms) and
    their Keepalived."""

    line: SharedLine
    net: PlantNetwork
    boxes: list[Box] = field(default_factory=list)
    keepaliveds: list[Keepalived] = field(default_factory=list)

    def start(self, folder: Path) -> tuple[Side, Side]:
        """Both boxes and their Keepalived started; once one is active: (its side, the
        other's). Which one VRRP elects depends on whose check answers first (both start as
        BACKUP, and with `nopreempt` the first MASTER stays)."""
        a_net, b_net = self.net.boxes
        tcp = {"host": "0.0.0.0", "port": MODBUS_PORT}
        paths = []
        for index, path in enumerate(self.line.paths):
            # Each box's adapter by a link of its own, as udev's /dev/serial/by-id/...: the link
            # goes when the adapter is pulled out (`unplug`).
            link = folder / f"usb-adapter-{index}"
            link.symlink_to(path)
            paths.append(str(link))
        wiring = (("a", a_net, paths[0], 0), ("b", b_net, paths[1], 500))
        for name, box_net, path, hold_off in wiring:
            command = box_net.exec(entry_point())
            self.boxes.append(Box(name, path, folder, "standby", hold_off, command, modbus_tcp=tcp))
        a, b = self.boxes
        self.keepaliveds.append(Keepalived(a_net, b_net, 150, a, folder / "ka"))
        self.keepaliveds.append(Keepalived(b_net, a_net, 100, b, folder / "kb"))
        deadline = time.monotonic() + 15  # VRRP's election (BACKUP first: ~1.8 s), the line
        while True:
            roles = [box.status()["role"] for box in self.boxes]
            if "active" in roles:
                sides = [self.side(index) for index in range(2)]
                active = roles.index("active")
                return sides[active], sides[1 - active]
            if time.monotonic() > deadline:
                logs = "\n".join(k.log.text[-3000:] for k in self.keepaliveds)
                raise AssertionError(f"no box active: {roles}\n{logs}")
            time.sleep(0.1)

    def side(self, index: int) -> Side:
        return Side(index, self.boxes[index], self.net.boxes[index], self.keepaliveds[index])

    def frames(self, side: Side) -> int:
        """Frames `side`'s box has transmitted on the line so far."""
        return frames(self.line)[side.index]

    def first_request(self, side: Side, since: float, within_s: float, log: Keepalived) -> float:
        """Seconds from `since` (a monotonic time) to `side`'s box's first frame on the line,
        waited for up to `within_s` (then `log`'s end says why not)."""
        while self.frames(side) == 0:
            assert time.monotonic() - since < within_s, log.log.text[-3000:]
            time.sleep(0.02)
        return time.monotonic() - since

    def assert_moved_to(self, side: Side) -> None:
        """The virtual address on `side`'s box, SCADA's next connection to it served by its
        gateway, now active; 0 collisions on the line."""
        assert holds_virtual(side.net)
        assert scada_read(self.net)[:2] == bytes([0x03, 0x02])  # SCADA's next connection
        assert side.box.status()["role"] == "active"
        assert self.line.stats()["collisions"] == 0

    def unplug(self, side: Side, folder: Path) -> None:
        """`side`'s box's USB adapter pulled out: its link and its port gone."""
        (folder / f"usb-adapter-{side.index}").unlink()
        assert self.line.command(f"unplug-master {side.index + 1}").startswith("ok")


@pytest.fixture
def site() -> Iterator[Site]:
    with shared_line(2, "--address", "1") as line, plant_network() as net:
        made = Site(line, net)
        try:
            yield made
        finally:
            for keepalived in made.keepaliveds:
                keepalived.stop()
            for box in made.boxes:
                box.stop()


def test_the_masters_box_serves_and_the_other_takes_over_when_it_dies(
    site: Site, tmp_path: Path
) -> None:
    active, other = site.start(tmp_path)
    time.sleep(0.5)  # the elected box's address settled
    assert holds_virtual(active.net)
    assert not holds_virtual(other.net)
    assert scada_read(site.net)[:2] == bytes([0x03, 0x02])
    assert other.box.status()["role"] == "standby"
    assert site.frames(other) == 0

    # The active box dies: its Keepalived and its gateway killed, its network gone.
    active.keepalived.kill()
    active.box.gateway.process.send_signal(signal.SIGKILL)
    active.box.gateway.process.wait(5)
    subprocess.run(site.net.on_lan("ip", "link", "set", active.net.port, "down"), check=True)
    killed = time.monotonic()
    first_request_s = site.first_request(other, killed, TAKEOVER_BOUND_S + 2, other.keepalived)
    print(f"first request from the new active {first_request_s:.2f} s after the kill")
    assert first_request_s < TAKEOVER_BOUND_S
    site.assert_moved_to(other)


def cable(site: Site, side: Side, where: str, state: str) -> None:
    """`side`'s box's network link set `state` (up, down): its own interface (`box`: the box's
    side, as `ip link set eth0 down` on it), or its switch port (`switch`: the box's interface
    loses its carrier, as when its cable is pulled)."""
    if where == "box":
        command = side.net.exec("ip", "link", "set", "eth0", state)
    else:
        command = site.net.on_lan("ip", "link", "set", side.net.port, state)
    subprocess.run(command, check=True)


@pytest.mark.parametrize("where", ["box", "switch"])
def test_the_active_box_s_network_gone_the_other_takes_the_line_and_keeps_it(
    site: Site, tmp_path: Path, where: str
) -> None:
    """Its cable pulled while both run: its Keepalived sees its interface down (FAULT: its
    notify asks `role standby`, and the gateway leaves the line), the other's hears no more
    adverts and is MASTER; the cable back, the old box is BACKUP (`nopreempt`) and its gateway
    never transmits again."""
    active, other = site.start(tmp_path)
    time.sleep(0.5)
    assert holds_virtual(active.net)
    cable(site, active, where, "down")
    cut, cut_at = time.monotonic(), datetime.now(UTC)
    moved_s = site.first_request(other, cut, TAKEOVER_BOUND_S + 2, other.keepalived)
    left_at = site.frames(active)  # it left the line before the other could take it
    # Its role asked by its notify script on FAULT, the other's on MASTER.
    left = active.box.wait_role("standby", 2.0)["last_change"]["at"]
    left_s = (datetime.fromisoformat(left) - cut_at).total_seconds()
    listened_s = other.box.status()["last_takeover_s"]
    print(
        f"first request from the other box {moved_s:.2f} s after the cut ({where}): the cut "
        f"box standby {left_s:.2f} s after it, the other asked to be active "
        f"{moved_s - listened_s:.2f} s after it, then listened {listened_s:.2f} s"
    )
    assert moved_s < TAKEOVER_BOUND_S
    assert "Entering FAULT STATE" in active.keepalived.log.text, active.keepalived.log.text
    site.assert_moved_to(other)

    # The cable back: BACKUP, its gateway standby, not one frame from it.
    cable(site, active, where, "up")
    active.keepalived.log.wait_for_count("Entering BACKUP STATE", 2, 10.0)
    time.sleep(2.0)  # four adverts: the other stays MASTER
    assert active.box.status()["role"] == "standby"
    assert not holds_virtual(active.net)
    assert site.frames(active) == left_at
    site.assert_moved_to(other)


def scada_reads_until_served(net: PlantNetwork, since: float, within_s: float) -> list[str]:
    """SCADA's reads through the virtual address, one after another, until one is served (the
    drive's value), for up to `within_s` from `since`: each `seconds: reply` (nothing: no
    answer within the read's 2 s, the address on its way). Never a wrong value."""
    answers = []
    while True:
        answer = scada_read(net)[:2]
        answers.append(f"{time.monotonic() - since:.2f}: {answer.hex() or 'nothing'}")
        assert answer in (SERVED, REFUSED, b""), answers
        if answer == SERVED:
            return answers
        assert time.monotonic() - since < within_s, answers
        time.sleep(0.1)


@pytest.mark.parametrize("dies", ["link back", "in the cut"])
def test_a_cut_link_makes_two_vrrp_masters_one_master_on_the_line_and_scada_served(
    site: Site, tmp_path: Path, dies: str
) -> None:
    """The link between the boxes cut, both reaching SCADA: both VRRP MASTER, the second asked
    active hears the first's polls and stays off the line (0 frames, 0 collisions); it gives
    the address up (the latch: fault file 1, FAULT) and the first's periodic gratuitous ARPs
    draw SCADA back to it: served through the cut. Then the active box dies, once the link is
    back (one box active, the other standby, served, before), or in the cut (a double fault):
    the line silent, the latch clears, and the other box takes the line."""
    active, other = site.start(tmp_path)
    time.sleep(0.5)
    site.net.cut()
    cut = time.monotonic()
    while not holds_virtual(other.net):  # it hears no adverts: MASTER too, and asked `active`
        assert time.monotonic() - cut < 10, other.keepalived.log.text[-2000:]
        time.sleep(0.05)
    master = time.monotonic()
    assert holds_virtual(active.net)
    # Both MASTER, both announcing the address: SCADA answered 0AH by the one, served by the
    # other, until the one that can't have the line gives the address up.
    answers = []
    while not other.box.says_unfit():
        answer = scada_read(site.net)[:2]
        answers.append(f"{time.monotonic() - master:.2f}: {answer.hex() or 'nothing'}")
        assert answer in (SERVED, REFUSED, b""), answers
        assert time.monotonic() - master < LATCH_S + 3, answers
    latched_s = time.monotonic() - master
    answers += scada_reads_until_served(site.net, master, SERVED_IN_CUT_S)
    served_s = time.monotonic() - master
    unfit = other.box.wait_role("standby", 2.0)
    print(
        f"the other box MASTER {master - cut:.2f} s after the cut; its fault file 1 "
        f"{latched_s:.2f} s after it, SCADA served {served_s:.2f} s after it: {answers}"
    )
    assert unfit["role"] == "standby", unfit  # its Keepalived FAULT: its notify asked standby
    assert unfit["fit"] is False
    assert "another master heard while this box was asked to be active" in unfit["unfit"]
    assert unfit["another_master_heard_s"] > LATCH_S
    assert other.box.says_unfit()
    assert "tracked file invt_gateway_fault now FAULT state" in other.keepalived.log.text
    assert not holds_virtual(other.net)
    assert not other.box.check_fails()  # the fault file says it: the track script stays up
    assert "gives the virtual address up" in other.box.gateway.log.text
    # The rest of the cut: SCADA served on every read, the line one master's.
    for _ in range(8):
        assert scada_read(site.net)[:2] == SERVED, time.monotonic() - master
        time.sleep(0.5)
    assert active.box.status()["role"] == "active"
    assert site.frames(other) == 0
    assert site.line.stats()["collisions"] == 0

    if dies == "link back":
        # One box active, the other standby (still FAULT: it hears the active); one master on
        # the line, SCADA served.
        site.net.cut(False)
        time.sleep(2.0)  # four adverts
        roles = [box.status()["role"] for box in (active.box, other.box)]
        assert roles == ["active", "standby"]
        assert scada_read(site.net)[:2] == SERVED
        assert site.frames(other) == 0
        assert site.line.stats()["collisions"] == 0

    # Then the active box dies: the line silent, the latch clears, the other box is fit again,
    # BACKUP, MASTER once no advert comes, and takes the line.
    active.keepalived.kill()
    active.box.gateway.process.send_signal(signal.SIGKILL)
    active.box.gateway.process.wait(5)
    killed = time.monotonic()
    first_request_s = site.first_request(other, killed, 10, other.keepalived)
    print(
        f"the active killed ({dies}): the other box's first request {first_request_s:.2f} s later"
    )
    assert first_request_s < TAKEOVER_AFTER_CUT_S
    assert "no other master heard" in other.box.gateway.log.text
    site.assert_moved_to(other)


def test_the_active_s_adapter_unplugged_the_address_and_the_line_move(
    site: Site, tmp_path: Path
) -> None:
    active, other = site.start(tmp_path)
    time.sleep(0.5)
    assert not active.box.says_unfit()
    site.unplug(active, tmp_path)
    unplugged = time.monotonic()
    # A second without a port, the fault file (Keepalived FAULT at once, its priority-0 advert),
    # the other box's skew, its notify script, the silence (over by then: the active box stopped
    # transmitting at the unplug).
    moved_s = site.first_request(other, unplugged, 12, active.keepalived)
    assert moved_s < TAKEOVER_BOUND_S, other.keepalived.log.text[-3000:]
    assert active.box.says_unfit()
    # How long it listened once asked (the rest was VRRP's, and the notify script's, part).
    listened_s = other.box.status()["last_takeover_s"]
    print(
        f"first request from the other box {moved_s:.2f} s after the unplug: asked to be "
        f"active {moved_s - listened_s:.2f} s after it, then listened {listened_s:.2f} s"
    )
    assert "tracked file invt_gateway_fault now FAULT state" in active.keepalived.log.text
    status = active.box.status()
    assert status["role"] == "standby"
    assert status["fit"] is False
    site.assert_moved_to(other)
