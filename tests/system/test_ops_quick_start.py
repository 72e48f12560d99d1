"""The README's run command, as a newcomer on Debian types it: a fresh clone, Debian's python3.

The command is taken from the README's Quick start, run in a `git clone` of this repository
(only what is committed, no .venv) with a PATH on which `python3` is Debian's `/usr/bin/python3`
(PEP 668 in force; pyenv or a virtual environment first on the PATH would hide what a fresh
machine does). It must make `.venv` with that Python, install the package from the package
index, start the demo, serve a read of state word 1 of drive 1 through `invt-gateway read --via`,
and stop on Ctrl-C. One test, the slow one: pip installs from the index (about half a minute).

Two options are added to the command: the Modbus-TCP and MQTT ports, free ones, because other
test runs on this machine may hold 5020 and 1883; the script passes them on to the demo.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
from pathlib import Path

import pytest

from tests.support import free_port
from tests.support.processes import LineCollector

REPOSITORY = Path(__file__).resolve().parents[2]
DEBIAN_PYTHON = Path("/usr/bin/python3")
# What `python3` is on a fresh Debian: its default PATH, without /usr/local (nothing there yet).
DEBIAN_PATH = "/usr/sbin:/usr/bin:/sbin:/bin"
INSTALL_AND_START_S = 400.0


def readme_run_command() -> str:
    """The first shell block of the README's Quick start."""
    readme = (REPOSITORY / "README.md").read_text(encoding="utf-8")
    quick_start = readme.split("## Quick start", 1)[1]
    block = re.search(r"```sh\n(.*?)```", quick_start, re.DOTALL)
    assert block is not None, "no ```sh block in the Quick start"
    lines = block.group(1).strip().splitlines()
    assert len(lines) == 1, f"the run command is one command: {lines}"
    return lines[0]


def debian_python_missing() -> str | None:
    """Why this test can't run here, or None."""
    if not Path("/etc/debian_version").exists() or not DEBIAN_PYTHON.exists():
        return "no Debian python3 (/usr/bin/python3 on Debian) on this machine"
    if shutil.which("git") is None or not (REPOSITORY / ".git").exists():
        return "not a git clone: nothing to clone from"
    probe = subprocess.run([str(DEBIAN_PYTHON), "-c", "import ensurepip"], check=False)
    if probe.returncode != 0 and os.geteuid() != 0:
        return "python3-venv is missing and installing it needs root (sudo would ask a password)"
    return None


@pytest.mark.timeout(INSTALL_AND_START_S + 60)
@pytest.mark.skipif(debian_python_missing() is not None, reason=str(debian_python_missing()))
def test_the_readme_run_command_on_debians_python_in_a_fresh_clone(tmp_path: Path) -> None:
    clone = tmp_path / "invt-gateway"
    subprocess.run(["git", "clone", "-q", str(REPOSITORY), str(clone)], check=True, timeout=60)
    environment = {**os.environ, "PATH": DEBIAN_PATH}
    for variable in ("VIRTUAL_ENV", "PYTHONPATH", "PYTHON", "PYENV_VERSION"):
        environment.pop(variable, None)
    # A fresh Debian has no python3-dev, so the build can't compile the engine room there; this
    # machine has Python's headers (for the tests' other builds): they are left out as if not.
    environment["INVT_GATEWAY_PURE_PYTHON"] = "1"
    assert shutil.which("python3", path=DEBIAN_PATH) == str(DEBIAN_PYTHON)
    tcp_port, mqtt_port = free_port(), free_port()
    command = f"{readme_run_command()} --port {tcp_port} --mqtt-port {mqtt_port}"

    demo = subprocess.Popen(
        ["bash", "-c", command],
        cwd=clone,
        env=environment,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,  # Ctrl-C reaches its process group, as in a terminal
    )
    output = LineCollector(demo.stdout)
    try:
        output.wait_for("Stop with Ctrl-C", INSTALL_AND_START_S)
        venv = (clone / ".venv" / "pyvenv.cfg").read_text(encoding="utf-8")
        assert "home = /usr/bin\n" in venv, venv  # made by Debian's python3, not another

        read = subprocess.run(
            [
                str(clone / ".venv" / "bin" / "invt-gateway"),
                *("read", "--via", f"tcp://127.0.0.1:{tcp_port}", "--address", "1", "2100H"),
            ],
            capture_output=True,
            text=True,
            timeout=30,
            check=False,
        )
        assert read.returncode == 0, read.stderr
        assert read.stdout.startswith("2100H  3 (stopped)"), read.stdout
    finally:
        if demo.poll() is None:
            os.killpg(demo.pid, signal.SIGINT)
        try:
            code = demo.wait(15)
        except subprocess.TimeoutExpired:
            os.killpg(demo.pid, signal.SIGKILL)
            code = demo.wait(5)
        output.join()
        if demo.stdout is not None:
            demo.stdout.close()
    assert code == 0, output.text
    assert f"Modbus-TCP on 127.0.0.1:{tcp_port}" in output.text
