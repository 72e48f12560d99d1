"""Two gateway boxes on one plant network, made of Linux network namespaces (as root): each box a
namespace with its `eth0`, a veth pair to a bridge in a third namespace (the plant's switch,
where SCADA sits), and Keepalived run in each box's namespace as it runs on a box.

    ns <lan>:  br0 10.248.0.1/24 (SCADA)  --  lan-a  <-veth->  eth0 10.248.0.11  ns <a>
                                          --  lan-b  <-veth->  eth0 10.248.0.12  ns <b>

`cut()` isolates the two boxes' switch ports from each other (`bridge link set ... isolated
on`): each still reaches SCADA, neither hears the other's VRRP adverts (a link cut between the
boxes, both then MASTER). The namespaces have names of their own per run, and go at the end.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

SUBNET = "10.248.0"
SCADA = f"{SUBNET}.1"
VIRTUAL = f"{SUBNET}.50"


def can_make_namespaces() -> str | None:
    """Why not, or None: root, and `ip`, `bridge` and keepalived there."""
    if os.geteuid() != 0:
        return "needs root (network namespaces)"
    for tool in ("ip", "bridge", "keepalived"):
        if shutil.which(tool) is None and not Path(f"/usr/sbin/{tool}").exists():
            return f"needs {tool}"
    return None


def run(*command: str) -> str:
    done = subprocess.run(command, capture_output=True, text=True, timeout=15, check=False)
    assert done.returncode == 0, f"{' '.join(command)}: {done.stderr}"
    return done.stdout


@dataclass(frozen=True)
class BoxNet:
    namespace: str
    address: str
    port: str
    """Its port on the switch (in the lan namespace)."""

    def exec(self, *command: str) -> list[str]:
        """`command` run in this box's namespace."""
        return ["ip", "netns", "exec", self.namespace, *command]

    def addresses(self) -> str:
        return run("ip", "-n", self.namespace, "-4", "addr", "show", "dev", "eth0")


@dataclass(frozen=True)
class PlantNetwork:
    lan: str
    boxes: tuple[BoxNet, BoxNet]

    def on_lan(self, *command: str) -> list[str]:
        """`command` run where SCADA is (the switch's namespace)."""
        return ["ip", "netns", "exec", self.lan, *command]

    def cut(self, cut: bool = True) -> None:
        for box in self.boxes:
            state = "on" if cut else "off"
            run(
                "ip",
                "netns",
                "exec",
                self.lan,
                "bridge",
                "link",
                "set",
                "dev",
                box.port,
                "isolated",
                state,
            )


@contextlib.contextmanager
def plant_network() -> Iterator[PlantNetwork]:
    tag = uuid.uuid4().hex[:6]
    lan = f"invt-lan-{tag}"
    boxes = (
        BoxNet(f"invt-a-{tag}", f"{SUBNET}.11", "lan-a"),
        BoxNet(f"invt-b-{tag}", f"{SUBNET}.12", "lan-b"),
    )
    made: list[str] = []
    try:
        for namespace in (lan, *(box.namespace for box in boxes)):
            run("ip", "netns", "add", namespace)
            made.append(namespace)
            run("ip", "-n", namespace, "link", "set", "lo", "up")
        run("ip", "-n", lan, "link", "add", "br0", "type", "bridge")
        run("ip", "-n", lan, "addr", "add", f"{SCADA}/24", "dev", "br0")
        run("ip", "-n", lan, "link", "set", "br0", "up")
        for box in boxes:
            run(
                "ip",
                "-n",
                lan,
                "link",
                "add",
                box.port,
                "type",
                "veth",
                "peer",
                "name",
                "eth0",
                "netns",
                box.namespace,
            )
            run("ip", "-n", lan, "link", "set", box.port, "master", "br0")
            run("ip", "-n", lan, "link", "set", box.port, "up")
            run("ip", "-n", box.namespace, "addr", "add", f"{box.address}/24", "dev", "eth0")
            run("ip", "-n", box.namespace, "link", "set", "eth0", "up")
        yield PlantNetwork(lan, boxes)
    finally:
        for namespace in reversed(made):
            subprocess.run(["ip", "netns", "del", namespace], capture_output=True, check=False)
