"""The control socket: `invt-gateway reload` asks the running gateway and hears its answer.

A signal can't answer back: `kill -HUP` and an `ExecReload=` that sends it succeed whether the
new configuration was applied or refused. The gateway therefore also listens on a unix stream
socket; a client sends one command line and reads the answer until the gateway hangs up.

Where the socket is, both sides work out alone from the configuration file's path (as given,
made absolute, symlinks left alone so a re-pointed link still names the same gateway):
`<temp dir>/invt-gateway-<uid>/<hash of the path>.sock`. The temp directory is the one place
writable in each way the gateway runs: systemd's `PrivateTmp=` /tmp, which `ExecReload=` shares
with `ExecStart=`; a container's own /tmp, which `docker exec` sees; and /tmp for a plain
`invt-gateway run`. The folder is the user's alone (mode 0700, owned by them), so only that user
and root can ask; a folder that is not so is not used.

The protocol, one exchange per connection: the client sends `reload\\n`; the gateway answers
with lines, each starting with the outcome (`applied: ...`, `refused: ...`, `skipped: ...`).
`role active\\n`, `role standby\\n` (`ok: ...` or `refused: ...`) and `role status\\n` (one
line of JSON) ask a gateway with `redundancy:` (`invt-gateway role`).
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import logging
import os
import socket
import stat
import tempfile
from collections.abc import Awaitable, Callable
from pathlib import Path

from gateway.errors import ControlUnavailable

log = logging.getLogger(__name__)

RELOAD = "reload"
ROLE = "role"
"""`role active|standby|status`: asked of a gateway with `redundancy:` (`invt-gateway role`)."""
MAX_COMMAND = 64
COMMAND_TIMEOUT_S = 5.0

Handler = Callable[[str], Awaitable[list[str]]]
"""A command in, the answer's lines out."""


def control_folder() -> Path:
    return Path(tempfile.gettempdir()) / f"invt-gateway-{os.getuid()}"


def control_path(config_path: str) -> Path:
    """The socket of the gateway that runs with `config_path`."""
    digest = hashlib.sha256(os.path.abspath(config_path).encode()).hexdigest()[:32]
    return control_folder() / f"{digest}.sock"


def _private_folder(folder: Path) -> None:
    """Make `folder` (0700) or check that it is this user's alone."""
    with contextlib.suppress(FileExistsError):
        folder.mkdir(mode=0o700)
    info = folder.lstat()
    if not stat.S_ISDIR(info.st_mode) or info.st_uid != os.getuid() or info.st_mode & 0o077:
        raise ControlUnavailable(f"{folder} is not a folder of this user's alone (mode 0700)")


class ControlServer:
    """Listens on the socket of `config_path` and answers each command with `handler`."""

    def __init__(self, config_path: str, handler: Handler) -> None:
        self.path = control_path(config_path)
        self.handler = handler
        self._server: asyncio.Server | None = None

    async def start(self) -> None:
        """Listen; ControlUnavailable if another gateway runs with the same file or the
        folder is not private."""
        try:
            _private_folder(self.path.parent)
            if self.path.exists():
                if _answers(self.path):
                    raise ControlUnavailable(f"another gateway answers on {self.path}")
                self.path.unlink()  # left by a gateway that was killed
            self._server = await asyncio.start_unix_server(self._serve, str(self.path))
        except OSError as exc:
            raise ControlUnavailable(f"{self.path}: {exc}") from exc

    async def stop(self) -> None:
        if self._server is None:
            return
        self._server.close()
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(self._server.wait_closed(), 1.0)
        with contextlib.suppress(OSError):
            self.path.unlink()
        self._server = None

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            line = await asyncio.wait_for(reader.readline(), COMMAND_TIMEOUT_S)
            command = line[:MAX_COMMAND].decode(errors="replace").strip()
            answer = await self.handler(command)
            writer.write("".join(f"{text}\n" for text in answer).encode())
            await writer.drain()
        except (TimeoutError, ConnectionError):
            pass  # a client that hung up or said nothing gets nothing more
        finally:
            writer.close()
            with contextlib.suppress(ConnectionError):
                await writer.wait_closed()


def _answers(path: Path) -> bool:
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as probe:
        try:
            probe.connect(str(path))
        except OSError:
            return False
        return True


def ask(config_path: str, command: str, timeout_s: float) -> list[str]:
    """Send `command` to the gateway running with `config_path`; its answer's lines."""
    path = control_path(config_path)
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as client:
        client.settimeout(timeout_s)
        try:
            client.connect(str(path))
        except OSError as exc:
            raise ControlUnavailable(
                f"no gateway runs with {os.path.abspath(config_path)} here "
                f"(its control socket {path}: {exc.strerror or exc})"
            ) from exc
        try:
            client.sendall(f"{command}\n".encode())
            chunks = []
            while chunk := client.recv(65536):
                chunks.append(chunk)
        except TimeoutError as exc:
            raise ControlUnavailable(f"no answer within {timeout_s:g} s on {path}") from exc
        except OSError as exc:
            raise ControlUnavailable(f"{path}: {exc}") from exc
    return b"".join(chunks).decode(errors="replace").splitlines()
