"""The systemd unit, checked by systemd itself, and the notify protocol spoken by a real
`invt-gateway run` to a real unix datagram socket, as systemd would bind it."""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from collections.abc import Iterator
from configparser import RawConfigParser
from pathlib import Path

import pytest

from gateway.config import StorageConfig
from gateway.console.sealing import KEY_SUFFIX
from gateway.control import control_path
from gateway.exit_codes import EXIT_CONFIG
from gateway.instruments.simulator import SimulatedLine
from gateway.store.owner import LOCK_SUFFIX
from tests.support import free_port
from tests.support.processes import entry_point, gateway_process

ROOT = Path(__file__).resolve().parents[2]
UNIT = ROOT / "config" / "invt-gateway.service"
SYSUSERS = ROOT / "config" / "invt-gateway.sysusers"
INSTALLED_PATH = "/opt/invt-gateway/bin/invt-gateway"
SYSTEMD_ANALYZE = shutil.which("systemd-analyze") or "/usr/bin/systemd-analyze"


def unit_settings() -> dict[str, list[str]]:
    """Each key of the unit with all its values (DeviceAllow= appears several times)."""
    settings: dict[str, list[str]] = {}
    for line in UNIT.read_text(encoding="utf-8").splitlines():
        line = line.strip()
        if line and not line.startswith(("#", "[")):
            key, _, value = line.partition("=")
            settings.setdefault(key, []).append(value)
    return settings


def test_systemd_analyze_verify_passes(tmp_path: Path) -> None:
    if not Path(SYSTEMD_ANALYZE).exists():
        pytest.fail("systemd-analyze not found: install the Debian package systemd")
    # verify checks that ExecStart's program exists: point it at this environment's script.
    # It doesn't look the user up (systemd-sysusers makes it: the test below).
    text = UNIT.read_text(encoding="utf-8")
    assert INSTALLED_PATH in text
    unit = tmp_path / UNIT.name
    unit.write_text(text.replace(INSTALLED_PATH, entry_point()), encoding="utf-8")
    result = subprocess.run(
        [SYSTEMD_ANALYZE, "verify", str(unit)],
        capture_output=True,
        text=True,
        timeout=30,
        check=False,
    )
    assert result.returncode == 0, result.stderr
    assert result.stderr == "", result.stderr  # not even a warning


def test_unit_runs_the_service_as_the_issue_asks() -> None:
    settings = unit_settings()
    parser = RawConfigParser(strict=False)
    parser.read_string(UNIT.read_text(encoding="utf-8"))
    assert parser.sections() == ["Unit", "Service", "Install"]
    expected = {
        "Type": ["notify"],
        "Restart": ["on-failure"],
        "NoNewPrivileges": ["yes"],
        "ProtectSystem": ["strict"],
        "PrivateTmp": ["yes"],
        "DevicePolicy": ["closed"],
        "SupplementaryGroups": ["dialout"],
        "User": ["invt-gateway"],
        # A bad configuration: restarting won't help. A failed start (a port taken) is
        # restarted: the port may be free on the next try.
        "RestartPreventExitStatus": [str(EXIT_CONFIG)],
        # The store, writable under ProtectSystem=strict, given to the user at each start.
        "StateDirectory": ["invt-gateway"],
        # The configuration's directory, writable under ProtectSystem=strict (the install
        # gives it to the user, with this mode, so the console can edit the file).
        "ConfigurationDirectory": ["invt-gateway"],
        "ConfigurationDirectoryMode": ["0750"],
        # systemctl reload: the config read again, and the reload fails when it is refused.
        "ExecReload": [f"{INSTALLED_PATH} reload --config /etc/invt-gateway/config.yaml"],
    }
    for key, values in expected.items():
        assert settings.get(key) == values, key
    assert settings["WatchdogSec"][0].rstrip("s").isdigit()
    # USB adapters, on-board UARTs, Raspberry Pi UARTs and SPI RS-485 hats.
    for group in ("ttyUSB", "ttyACM", "ttyS", "ttyAMA", "ttySC"):
        assert f"char-{group} rw" in settings["DeviceAllow"], group
    assert settings["ExecStart"] == [f"{INSTALLED_PATH} run --config /etc/invt-gateway/config.yaml"]
    # A static user (systemd-sysusers): a dynamic one's uid may own nothing that outlives it.
    assert "DynamicUser" not in settings


def test_the_sysusers_file_makes_the_units_user(tmp_path: Path) -> None:
    """The docs' `systemd-sysusers` step, run on an empty system root: the unit's User= exists
    after it, a system user with no login shell, its group of the same name."""
    (tmp_path / "etc").mkdir()
    (tmp_path / "etc" / "passwd").write_text("root:x:0:0:root:/root:/bin/bash\n")
    (tmp_path / "etc" / "group").write_text("root:x:0:\ndialout:x:20:\n")
    sysusers = shutil.which("systemd-sysusers") or "/usr/bin/systemd-sysusers"
    result = subprocess.run(
        [sysusers, f"--root={tmp_path}", str(SYSUSERS)],
        capture_output=True,
        text=True,
        timeout=30,
        check=False,
    )
    assert result.returncode == 0, result.stderr
    (user,) = unit_settings()["User"]
    made = {
        line.split(":")[0]: line.split(":")
        for line in (tmp_path / "etc" / "passwd").read_text().splitlines()
    }
    _, _, uid, gid, _, _, shell = made[user]
    assert 0 < int(uid) < 1000  # a system user's
    assert shell == "/usr/sbin/nologin"
    groups = dict(
        line.split(":")[::2] for line in (tmp_path / "etc" / "group").read_text().splitlines()
    )
    assert groups[user] == gid


def operations_install_lines() -> list[str]:
    """The systemd block of the Operations page, one command a line, comments dropped."""
    page = (ROOT / "docs" / "pages" / "operations.md").read_text(encoding="utf-8")
    block = page.split("\n## systemd\n", 1)[1].split("```sh\n", 1)[1].split("```", 1)[0]
    return [line.split("  #")[0].strip() for line in block.splitlines() if line.strip()]


def test_the_docs_install_gives_the_service_what_it_writes() -> None:
    """Every path the gateway writes under the unit is in a directory the unit makes writable
    (ConfigurationDirectory=, StateDirectory=, PrivateTmp=) and that the docs' install lines or
    systemd give the service's user: the configuration file and the new file renamed over it
    (the console's editor), the store with its lock and the key sealing the versions' secrets,
    the control socket of `invt-gateway reload`."""
    settings = unit_settings()
    (user,) = settings["User"]
    etc = Path("/etc") / settings["ConfigurationDirectory"][0]
    state = Path("/var/lib") / settings["StateDirectory"][0]
    config = Path(settings["ExecStart"][0].split("--config ")[1])
    assert config.parent == etc  # the new file is made beside it, then renamed over it
    lines = operations_install_lines()
    mode = settings["ConfigurationDirectoryMode"][0]
    assert f"install -d -o {user} -g {user} -m {mode} {etc}" in lines
    (placed,) = [
        line for line in lines if line.startswith("install ") and line.endswith(f" {config}")
    ]
    assert placed.startswith(f"install -o {user} -g {user} -m 0640 ")
    assert f"install -m 0644 config/{SYSUSERS.name} /etc/sysusers.d/invt-gateway.conf" in lines
    assert "systemd-sysusers /etc/sysusers.d/invt-gateway.conf" in lines
    # The store: where storage.path defaults to with $STATE_DIRECTORY as systemd sets it.
    store = Path(StorageConfig().resolved_path("cabinet-a", {"STATE_DIRECTORY": str(state)}))
    assert store.parent == state
    for beside in (LOCK_SUFFIX, KEY_SUFFIX, "-wal", "-shm"):
        assert Path(f"{store}{beside}").parent == state
    # The control socket: in the temp folder, the unit's own (PrivateTmp=).
    assert settings["PrivateTmp"] == ["yes"]
    assert control_path(str(config)).is_relative_to(tempfile.gettempdir())


@contextlib.contextmanager
def notify_socket() -> Iterator[tuple[str, socket.socket]]:
    """A unix datagram socket bound where NOTIFY_SOCKET will point (short path: 108 bytes max)."""
    directory = tempfile.mkdtemp(prefix="notify-", dir="/tmp")
    path = os.path.join(directory, "notify")
    receiver = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    receiver.bind(path)
    try:
        yield path, receiver
    finally:
        receiver.close()
        shutil.rmtree(directory, ignore_errors=True)


def receive(receiver: socket.socket, until: str, timeout_s: float) -> list[dict[str, str]]:
    """Datagrams as {KEY: value} until one carries the key `until`."""
    messages: list[dict[str, str]] = []
    deadline = time.monotonic() + timeout_s
    while True:
        receiver.settimeout(max(deadline - time.monotonic(), 0.01))
        try:
            data = receiver.recv(4096)
        except TimeoutError:
            raise AssertionError(f"no {until} within {timeout_s} s; got {messages}") from None
        fields = dict(line.split("=", 1) for line in data.decode().splitlines() if "=" in line)
        messages.append(fields)
        if until in fields:
            return messages


def test_ready_watchdog_and_stopping_reach_the_notify_socket(tmp_path: Path) -> None:
    with (
        SimulatedLine(addresses=[1], baudrate=115200, parity="E") as line,
        notify_socket() as (path, receiver),
    ):
        config = {
            "gateway_id": "notify",
            "modbus_tcp": {"host": "127.0.0.1", "port": free_port()},
            "buses": [{"name": "line1", "port": line.path, "baudrate": 115200}],
            "drives": [{"name": "pump1", "bus": "line1", "address": 1}],
        }
        # 200 ms: the gateway must ping every 100 ms.
        env = {"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "200000"}
        with gateway_process(config, tmp_path, env) as gateway:
            before_ready = receive(receiver, "READY", 15.0)
            ready = before_ready[-1]
            assert ready["READY"] == "1"
            assert ready["MAINPID"] == str(gateway.process.pid)
            assert ready["STATUS"].startswith("ready: 1 drives on 1 buses, Modbus-TCP on 127.0.0.1")
            # The log line and the notification come from the same moment: after start-up
            # (the log reader thread may see the line a moment after the datagram arrives).
            assert "ready:" in gateway.log.wait_for("ready:", 5.0)

            started = time.monotonic()
            pings = receive(receiver, "WATCHDOG", 1.0)
            for _ in range(4):
                pings += receive(receiver, "WATCHDOG", 1.0)
            elapsed = time.monotonic() - started
            assert sum("WATCHDOG" in m for m in pings) >= 5
            # Pings every 0.1 s; a generous bound so a loaded CI machine doesn't flake, while a
            # loop that stopped pinging would send none at all.
            assert elapsed < 3.0, f"5 pings took {elapsed:.2f} s, WatchdogSec is 0.2 s"

            gateway.signal(signal.SIGTERM)
            stopping = receive(receiver, "STOPPING", 2.0)[-1]
            assert stopping["STOPPING"] == "1"
            assert gateway.wait(2.0) == 0


def test_abstract_notify_socket_and_no_watchdog_without_watchdog_usec(tmp_path: Path) -> None:
    name = f"invt-gateway-test-{os.getpid()}-{time.monotonic_ns()}"
    receiver = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    receiver.bind("\0" + name)
    with SimulatedLine(addresses=[1], baudrate=115200, parity="E") as line, receiver:
        config = {
            "gateway_id": "notify2",
            "modbus_tcp": {"host": "127.0.0.1", "port": free_port()},
            "buses": [{"name": "line1", "port": line.path, "baudrate": 115200}],
        }
        with gateway_process(config, tmp_path, {"NOTIFY_SOCKET": "@" + name}) as gateway:
            assert receive(receiver, "READY", 15.0)[-1]["READY"] == "1"
            gateway.signal(signal.SIGINT)
            after = receive(receiver, "STOPPING", 2.0)
            assert not [m for m in after if "WATCHDOG" in m]
            assert gateway.wait(2.0) == 0
