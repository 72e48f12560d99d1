"""The console's configuration editor where the gateway is installed, not run as root from a
checkout: a real `invt-gateway run` as a user of its own (setpriv), its configuration in a
directory that user owns as the systemd install leaves it (`install -d -o invt-gateway -m 0750`,
the file 0640, the store in a 0700 state directory as StateDirectory= gives it). Apply works
there; and where the file can't be written (a directory still root's, a Docker volume mounted
`:ro`, a file mounted on its own, a file marked read-only), the page says so when the file is
loaded and an apply is refused naming the file and why, nothing kept or changed.

Running as another user and mounting need root (the development container runs the tests as
root); elsewhere these tests are skipped, and say why."""

from __future__ import annotations

import asyncio
import contextlib
import os
import pwd
import shlex
import shutil
import subprocess
import tempfile
from collections.abc import AsyncIterator, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import aiohttp
import pytest
import yaml

from gateway.instruments.simulator import SimulatedLine
from gateway.passwords import hash_password
from tests.support import free_port
from tests.support.console_support import ConsoleClient
from tests.support.processes import ROOT, GatewayProcess, entry_point, gateway_process
from tests.support.site import DOCS
from tests.support.small_disk import read_only

ADMIN_PASSWORD = "admin-secret-444"
OPERATIONS = DOCS / "pages" / "operations.md"
DOCKERFILE = ROOT / "Dockerfile"
SERVICE_USER = "invt-gateway"
"""The systemd unit's User= (config/invt-gateway.sysusers makes it)."""


def service_uid() -> int:
    """A uid no account of this box has, as a fresh system user's is to every other file."""
    uid = 64123
    while True:
        try:
            pwd.getpwuid(uid)
        except KeyError:
            return uid
        uid += 1


def container_uid() -> int:
    """The image's USER (a number, so an orchestrator can tell it isn't root)."""
    users = [
        line.split()[1] for line in DOCKERFILE.read_text().splitlines() if line.startswith("USER ")
    ]
    return int(users[-1])


def shell_block(section: str) -> list[str]:
    """The commands of the first `sh` block under `## section` of the Operations page, each
    continuation joined, comments dropped."""
    text = OPERATIONS.read_text(encoding="utf-8").split(f"\n## {section}\n", 1)[1]
    block = text.split("```sh\n", 1)[1].split("```", 1)[0].replace("\\\n", "")
    return [line.split("  #")[0].strip() for line in block.splitlines() if line.strip()]


def install_steps(section: str) -> tuple[list[str], list[str]]:
    """The page's `install -d` line for the configuration's directory and its `install` line
    for the file, as argument lists."""
    steps = [shlex.split(line) for line in shell_block(section) if line.startswith("install ")]
    directory = [step for step in steps if step[1] == "-d" and "invt-gateway" in step[-1]]
    file = [step for step in steps if step[-1].endswith("/config.yaml")]
    (made,), (placed,) = directory, file
    return made, placed


@dataclass(frozen=True)
class Install:
    """The directories an install gives the service: the configuration's and the store's."""

    uid: int
    etc: Path
    state: Path
    config_step: list[str]
    """The page's `install` line for the file, its paths still the page's."""

    def as_service(self) -> list[str]:
        """The gateway's command line run as the service's user, no group, no capability."""
        return [
            "setpriv",
            f"--reuid={self.uid}",
            f"--regid={self.uid}",
            "--clear-groups",
            "--inh-caps=-all",
            entry_point(),
        ]

    def give(self, device: str) -> None:
        """The serial device (the simulated line's pty) to the service's user."""
        os.chown(os.path.realpath(device), self.uid, self.uid)

    def place(self, text: str, name: str) -> Path:
        """`text` put in the configuration's directory as `name` by the page's own line."""
        source = self.state.parent / "config.source.yaml"
        source.write_text(text, encoding="utf-8")
        step = [*self.config_step[:-2], str(source), str(self.etc / name)]
        subprocess.run(_owned_by(step, self.uid), check=True)
        source.unlink()
        return self.etc / name


def _owned_by(step: list[str], uid: int) -> list[str]:
    """`step` with its `-o`/`-g` owner the test's uid (the page's user has no account here)."""
    return [str(uid) if index and step[index - 1] in ("-o", "-g") else word
            for index, word in enumerate(step)]  # fmt: skip


@contextlib.contextmanager
def installed(section: str = "systemd") -> Iterator[Install]:
    """The configuration's directory made by the Operations page's own lines (`section`: the
    systemd install or the Docker run), the store's as the unit's StateDirectoryMode= or the
    image's `install -d` gives it, in a folder of /tmp the service's user can reach (pytest's
    tmp_path is root's alone)."""
    if os.geteuid() != 0:
        pytest.skip("running the gateway as a user of its own needs root")
    if shutil.which("setpriv") is None:
        pytest.skip("setpriv (util-linux) is not installed")
    uid = service_uid() if section == "systemd" else container_uid()
    probe = subprocess.run(
        [
            "setpriv",
            f"--reuid={uid}",
            f"--regid={uid}",
            "--clear-groups",
            entry_point(),
            "--version",
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    if probe.returncode != 0:
        pytest.skip(f"this environment's invt-gateway can't run as uid {uid}: {probe.stderr}")
    make_directory, place_file = install_steps(section)
    base = Path(tempfile.mkdtemp(prefix="invt-gateway-install-", dir="/tmp"))
    try:
        base.chmod(0o755)
        etc, state = base / "etc-invt-gateway", base / "var-lib-invt-gateway"
        subprocess.run(_owned_by([*make_directory[:-1], str(etc)], uid), check=True)
        state.mkdir(mode=0o700)
        os.chown(state, uid, uid)
        yield Install(uid, etc, state, place_file)
    finally:
        shutil.rmtree(base, ignore_errors=True)


@contextlib.contextmanager
def mounted_on_itself(path: Path) -> Iterator[None]:
    """`path` bound over itself, writable: as `docker run -v FILE:FILE` mounts one file."""
    subprocess.run(["mount", "--bind", str(path), str(path)], check=True)
    try:
        yield
    finally:
        subprocess.run(["umount", str(path)], check=True)


def config(line: SimulatedLine, console_port: int) -> dict[str, Any]:
    admin = {"name": "ada", "password_hash": hash_password(ADMIN_PASSWORD), "role": "admin"}
    return {
        "gateway_id": "installed",
        "modbus_tcp": {"host": "127.0.0.1", "port": free_port()},
        "buses": [{"name": "line1", "port": line.path, "baudrate": 115200, "timeout_ms": 100}],
        "drives": [{"name": "pump1", "bus": "line1", "address": 1}],
        "console": {"enabled": True, "host": "127.0.0.1", "port": console_port, "users": [admin]},
    }


@contextlib.asynccontextmanager
async def service(
    line: SimulatedLine, install: Install
) -> AsyncIterator[tuple[GatewayProcess, int]]:
    """The gateway as the unit or the image starts it: its user, the store's directory in
    $STATE_DIRECTORY, the configuration placed by the page's line; and its console's port."""
    install.give(line.path)  # what dialout does for the service
    port = free_port()
    written = config(line, port)
    # Placed by the page's own `install` line, under the name the gateway process writes
    # (writing it again keeps the owner and mode the line gave).
    install.place(yaml.safe_dump(written), f"gateway-{written['gateway_id']}.yaml")
    env = {"STATE_DIRECTORY": str(install.state)}
    with gateway_process(written, install.etc, env, install.as_service()) as gateway:
        await asyncio.to_thread(gateway.wait_ready)
        yield gateway, port


@contextlib.asynccontextmanager
async def admin_of(port: int) -> AsyncIterator[ConsoleClient]:
    async with aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True)) as session:
        client = ConsoleClient(session, f"http://127.0.0.1:{port}")
        assert (await client.login("ada", ADMIN_PASSWORD)).status == 200
        yield client


async def refused_apply(admin: ConsoleClient, gateway: GatewayProcess) -> str:
    """What the page shows when the file is loaded, and the apply's refusal: the same words,
    nothing written, nothing kept (asserted here)."""
    before = gateway.config_file.read_bytes()
    versions = (await admin.get_json("/api/config/versions"))["versions"]
    shown = await admin.get_json("/api/config/file")
    assert shown["read_only"], shown
    longer = shown["text"].replace("timeout_ms: 100", "timeout_ms: 160")
    status, refused = await admin.post("/api/config/apply", {"text": longer, "base": shown["base"]})
    assert status == 409, refused
    assert refused["error"] == shown["read_only"]
    assert gateway.config_file.read_bytes() == before
    assert (await admin.get_json("/api/config/versions"))["versions"] == versions
    assert sorted(p.name for p in gateway.config_file.parent.iterdir()) == [
        gateway.config_file.name
    ]  # no new file left beside it
    return str(refused["error"])


@pytest.mark.parametrize("section", ["systemd", "Docker"])
async def test_an_admin_applies_as_the_service_user_in_the_directory_the_install_gives(
    line: SimulatedLine, section: str
) -> None:
    """The Operations page's install lines, run: the systemd install (a system user of its own)
    or the Docker run (the image's user 10001, the host directory it mounts)."""
    with installed(section) as install:
        async with service(line, install) as (gateway, port), admin_of(port) as admin:
            assert gateway.process.pid is not None
            assert os.stat(f"/proc/{gateway.process.pid}").st_uid == install.uid
            shown = await admin.get_json("/api/config/file")
            assert shown["read_only"] is None
            longer = shown["text"].replace("timeout_ms: 100", "timeout_ms: 150")
            status, applied = await admin.post(
                "/api/config/apply", {"text": longer, "note": "longer cable", "base": shown["base"]}
            )
            assert status == 200, applied
            assert applied["version"] == 2
            assert applied["changed"] == ["buses reopened: line1"]
            written = gateway.config_file.stat()
            assert (written.st_uid, oct(written.st_mode & 0o777)) == (install.uid, "0o640")
            assert yaml.safe_load(gateway.config_file.read_text())["buses"][0]["timeout_ms"] == 150
            status, rolled = await admin.post("/api/config/versions/1/rollback", {})
            assert status == 200, rolled
            assert rolled["version"] == 3
            # Everything it wrote is in the two directories the unit makes writable: the
            # file alone in /etc (no temporary file left), the versions in the store.
            assert [p.name for p in install.etc.iterdir()] == [gateway.config_file.name]
            stored = {p.name for p in install.state.iterdir()}
            assert "events-installed.db" in stored
            assert "events-installed.db.secrets-key" in stored  # the versions' secrets sealed
            assert all(p.stat().st_uid == install.uid for p in install.state.iterdir())


async def test_where_the_file_cant_be_written_the_console_says_why_and_changes_nothing(
    line: SimulatedLine,
) -> None:
    with installed() as install:
        async with service(line, install) as (gateway, port), admin_of(port) as admin:
            path = gateway.config_file

            # The install of the days of DynamicUser=: the directory root's (`install -d`).
            os.chown(install.etc, 0, 0)
            install.etc.chmod(0o755)
            said = await refused_apply(admin, gateway)
            assert said.startswith(f"{path} cannot be changed from the console: ")
            assert f"may not write in its directory {install.etc} (root's, mode 0755)" in said
            assert f"the gateway runs as uid {install.uid}, which may not" in said
            os.chown(install.etc, install.uid, install.uid)
            install.etc.chmod(0o750)

            # The file root's as the old install left it (`install -m 0644`): readable only.
            os.chown(path, 0, 0)
            path.chmod(0o644)
            said = await refused_apply(admin, gateway)
            assert "may not write it (root's, mode 0644)" in said
            os.chown(path, install.uid, install.uid)
            path.chmod(0o640)

            # Marked read-only on purpose.
            path.chmod(0o440)
            said = await refused_apply(admin, gateway)
            assert "the file is marked read-only (mode 0440)" in said
            path.chmod(0o640)

            # The documented Docker run before: the directory mounted `:ro`.
            with read_only(install.etc):
                said = await refused_apply(admin, gateway)
            assert "it is on a read-only mount" in said

            # A file mounted on its own: even writable, no new file can be renamed over it.
            with mounted_on_itself(path):
                said = await refused_apply(admin, gateway)
            assert "the file is mounted on its own" in said
            assert "mount its directory instead" in said

            # And once the install is right again, the same edit applies.
            shown = await admin.get_json("/api/config/file")
            assert shown["read_only"] is None
            status, applied = await admin.post(
                "/api/config/apply", {"text": shown["text"], "base": shown["base"]}
            )
            assert status == 200, applied
