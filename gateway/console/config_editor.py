"""Editing the configuration from the console (the admin role): check, keep, apply, roll back.

    check     the text as `check-config` checks a file (every key, its type and range, the
              cross-checks; the missing ports and overloaded lines as warnings), and what
              applying it would change now and what would wait for a restart (the reload's
              own plan), without applying anything
    apply     a text that checks out is kept in the store as a new version (who, when, a
              note), written over the configuration file (a new file renamed over it: never
              half-written) and applied through the live reload, as SIGHUP or `invt-gateway
              reload` would; the previous versions stay, each with its diff
    rollback  an earlier version applied again, as a new version

The file is the truth a restart reads, so it is written before the reload reads it; the
version is kept first, so the store always holds the text the file has. Before the first edit
the file as found is kept as version 1 ("as found"), so the first change can be rolled back too.

Secrets are not sent to the browser: a value of a key named like a secret (`password`,
`token`...) shows as `***`; a `***` sent back stands for the value the file has at that place
(the same key, counted from the top), so an edit elsewhere keeps the secrets as they are.
"""

from __future__ import annotations

import asyncio
import difflib
import os
import re
import tempfile
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any, Final, Protocol

from gateway.errors import StoreError
from gateway.settings import GatewaySettings
from gateway.settings.editing import Checked, check_text
from gateway.settings.shown import MASK, SECRET_WORDS
from gateway.store.records import ConfigVersion

MAX_TEXT: Final = 256 * 1024
"""A configuration of a few hundred drives is tens of kB."""
FOUND: Final = "as found in the file before the first edit from the console"
_LINE: Final = re.compile(
    r"^(?P<lead>\s*(?:-\s+)?)(?P<key>[A-Za-z_][A-Za-z0-9_]*)(?P<colon>\s*:[ \t]+)(?P<value>\S.*)$"
)


class VersionStore(Protocol):
    """The store's side (`gateway.store.EventStore`)."""

    async def add_config_version(self, user: str, text: str, note: str) -> int: ...

    async def config_versions(self) -> list[ConfigVersion]: ...


class EditRefused(Exception):
    """The edit was not applied; `status` the HTTP status that says why."""

    def __init__(self, status: int, message: str, checked: Checked | None = None) -> None:
        super().__init__(message)
        self.status = status
        self.checked = checked


class ConfigEditor:
    def __init__(
        self,
        path: str,
        reload: Callable[[], Awaitable[list[str]]],
        versions: VersionStore,
        running: Callable[[], GatewaySettings],
        mqtt_running: Callable[[], bool],
    ) -> None:
        self.path = path
        self.reload = reload
        self.versions = versions
        self.running = running
        self.mqtt_running = mqtt_running
        self._one_at_a_time = asyncio.Lock()

    # -- reading -------------------------------------------------------------------------------

    async def current(self) -> dict[str, Any]:
        text = await self._read_file()
        return {"path": self.path, "text": masked(text)}

    async def history(self) -> list[dict[str, Any]]:
        """Every version kept, newest first, each with its diff from the one before."""
        found = await self._versions()
        shown = []
        for index, version in enumerate(found):
            before = found[index + 1].text if index + 1 < len(found) else ""
            shown.append({**version.summary(), "diff": diff(before, version.text, version.id)})
        return shown

    async def version(self, number: int) -> dict[str, Any]:
        found = {v.id: v for v in await self._versions()}
        if number not in found:
            raise EditRefused(404, f"version: no version {number} is kept")
        return {**found[number].summary(), "text": masked(found[number].text)}

    # -- checking and applying ---------------------------------------------------------------

    async def check(self, text: str) -> Checked:
        """`text` (with `***` for the secrets kept) checked as `check-config` checks a file."""
        full = unmasked(text, await self._read_file())
        return await asyncio.to_thread(self._check, full)

    async def apply(self, text: str, user: str, note: str) -> dict[str, Any]:
        async with self._one_at_a_time:
            current = await self._read_file()
            full = unmasked(text, current)
            checked = await asyncio.to_thread(self._check, full)
            if not checked.ok:
                raise EditRefused(400, "the configuration does not check out", checked)
            number = await self._keep(user, full, note, current)
            await self._write_file(full)
            outcome = await self.reload()
            applied = bool(outcome) and all(line.startswith("applied:") for line in outcome)
            if not applied:
                # The running configuration stayed: the file says so again.
                await self._write_file(current)
                raise EditRefused(409, "; ".join(outcome) or "the reload did not answer", checked)
            return {"version": number, "outcome": outcome, **checked.to_json()}

    async def rollback(self, number: int, user: str) -> dict[str, Any]:
        found = {v.id: v for v in await self._versions()}
        if number not in found:
            raise EditRefused(404, f"version: no version {number} is kept")
        return await self.apply(found[number].text, user, f"rollback to version {number}")

    # -- inside --------------------------------------------------------------------------------

    def _check(self, text: str) -> Checked:
        if len(text.encode()) > MAX_TEXT:
            return Checked([("", f"the text is longer than {MAX_TEXT // 1024} kB")])
        return check_text(text, self.path, self.running(), self.mqtt_running())

    async def _keep(self, user: str, text: str, note: str, current: str) -> int:
        try:
            if not await self.versions.config_versions():
                await self.versions.add_config_version("(file)", current, FOUND)
            return await self.versions.add_config_version(user, text, note)
        except StoreError as exc:
            raise EditRefused(409, f"not applied: the version cannot be kept: {exc}") from None

    async def _versions(self) -> list[ConfigVersion]:
        try:
            return await self.versions.config_versions()
        except StoreError as exc:
            raise EditRefused(409, f"the versions cannot be read: {exc}") from None

    async def _read_file(self) -> str:
        try:
            return await asyncio.to_thread(Path(self.path).read_text, encoding="utf-8")
        except OSError as exc:
            raise EditRefused(409, f"{self.path}: cannot read it: {exc.strerror or exc}") from None

    async def _write_file(self, text: str) -> None:
        try:
            await asyncio.to_thread(_replace_file, self.path, text)
        except OSError as exc:
            raise EditRefused(
                409,
                f"{self.path}: cannot write it: {exc.strerror or exc} (the service user needs "
                "write access to the file and its directory to edit from the console)",
            ) from None


def _replace_file(path: str, text: str) -> None:
    """A new file beside it, synced, renamed over it: a crash leaves the old or the new."""
    target = Path(path)
    mode = target.stat().st_mode & 0o777 if target.exists() else 0o640
    handle, temporary = tempfile.mkstemp(prefix=f".{target.name}.", dir=target.parent)
    try:
        with os.fdopen(handle, "w", encoding="utf-8") as out:
            out.write(text)
            out.flush()
            os.fsync(out.fileno())
        os.chmod(temporary, mode)
        os.replace(temporary, target)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise


def diff(before: str, after: str, number: int) -> str:
    """A unified diff, secrets masked on both sides."""
    lines = difflib.unified_diff(
        masked(before).splitlines(keepends=True),
        masked(after).splitlines(keepends=True),
        fromfile=f"version {number - 1}" if before else "(nothing)",
        tofile=f"version {number}",
    )
    return "".join(lines)


def _secret(key: str) -> bool:
    return any(word in key.lower() for word in SECRET_WORDS)


def masked(text: str) -> str:
    """`text` with the value of every key named like a secret shown as `***`."""
    out = []
    for line in text.splitlines(keepends=True):
        match = _LINE.match(line.rstrip("\r\n"))
        if match and _secret(match["key"]) and match["value"] not in ("null", "~"):
            ending = line[len(line.rstrip("\r\n")) :]
            line = f"{match['lead']}{match['key']}{match['colon']}{MASK}{ending}"
        out.append(line)
    return "".join(out)


def unmasked(text: str, original: str) -> str:
    """`text` with each `***` value of a secret key replaced by the value `original` has for
    that key at the same place (its n-th occurrence). A `***` with nothing to stand for is left
    as it is: the check then says the key's value is wrong."""
    kept: dict[str, list[str]] = {}
    for line in original.splitlines():
        match = _LINE.match(line)
        if match and _secret(match["key"]):
            kept.setdefault(match["key"], []).append(match["value"])
    seen: dict[str, int] = {}
    out = []
    for line in text.splitlines(keepends=True):
        bare = line.rstrip("\r\n")
        match = _LINE.match(bare)
        if match and _secret(match["key"]):
            index = seen.get(match["key"], 0)
            seen[match["key"]] = index + 1
            values = kept.get(match["key"], [])
            if match["value"].strip() in (MASK, f'"{MASK}"', f"'{MASK}'") and index < len(values):
                ending = line[len(bare) :]
                line = f"{match['lead']}{match['key']}{match['colon']}{values[index]}{ending}"
        out.append(line)
    return "".join(out)
