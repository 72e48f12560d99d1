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
version is kept first, so the store always holds the text the file has. A file the console can't
write (a read-only mount, a file mounted alone, another user's: `config_access` says why) is
said so when it is loaded and refused before anything is kept. Before the first edit
the file as found is kept as version 1 ("as found"), so the first change can be rolled back too.

Secrets are not sent to the browser: the value of a key named like a secret (`password`,
`token`...) shows as `"***N"`, the file's N-th secret; a `"***N"` sent back stands for that
value, wherever its line went (a user removed above another leaves the other's hash with it).
The text carries the file's fingerprint (`base`): an edit of a file changed meanwhile is
refused (409) rather than numbered against the wrong secrets. A mask that stands for no secret of
the file (`"***99"`, or `"***"` copied from a diff) is refused at its key, never kept as the
value. The versions kept in the store have each secret sealed with the box's key
(`gateway.console.sealing`), never in clear; a rollback opens them.
"""

from __future__ import annotations

import asyncio
import contextlib
import difflib
import hashlib
import os
import re
import tempfile
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final, Protocol

from gateway.console import config_access
from gateway.console.config_check import Checked, check_text
from gateway.console.sealing import SecretSeal
from gateway.errors import EditRefused, StoreError
from gateway.settings import GatewaySettings
from gateway.settings.shown import MASK, SECRET_WORDS
from gateway.store.records import ConfigVersion

MAX_TEXT: Final = 256 * 1024
"""A configuration of a few hundred drives is tens of kB."""
FOUND: Final = "as found in the file before the first edit from the console"
_BLOCK: Final = re.compile(
    r"^(?P<lead>\s*(?:-\s+)?)(?P<key>[A-Za-z_][A-Za-z0-9_]*)[ \t]*:[ \t]+"
    r"(?P<value>\"(?:[^\"\\]|\\.)*\"|'(?:[^']|'')*'|[^\s#](?:[^#]*?[^\s#])?)"
    r"(?:[ \t]+#.*)?[ \t]*$"
)
"""A line's own key and its value (quoted, or plain up to a comment)."""
_FLOW: Final = re.compile(
    r"(?<![A-Za-z0-9_])(?P<key>[A-Za-z_][A-Za-z0-9_]*)[ \t]*:[ \t]+"
    r"(?P<value>\"(?:[^\"\\]|\\.)*\"|'(?:[^']|'')*'|[^\s,{}\[\]#][^,{}\[\]#]*)"
)
"""A key and its value inside a flow mapping (up to `,` or `}`)."""
_TOKEN: Final = re.compile(r"""(?P<quote>["']?)\*\*\*(?P<number>\d+)(?P=quote)""")
_MASK_LIKE: Final = re.compile(r"""(["']?)\*\*\*\d*\1""")
"""A secret's value that is a mask: `***`, `***N`, quoted or not."""


class VersionStore(Protocol):
    """The store's side (`gateway.store.EventStore`)."""

    async def add_config_version(self, user: str, text: str, note: str) -> int: ...

    async def remove_config_version(self, number: int) -> None: ...

    async def config_versions(self) -> list[ConfigVersion]: ...


class ConfigEditor:
    def __init__(
        self,
        path: str,
        reload: Callable[[], Awaitable[list[str]]],
        versions: VersionStore,
        running: Callable[[], GatewaySettings],
        mqtt_running: Callable[[], bool],
        seal: SecretSeal,
    ) -> None:
        self.path = path
        self.seal = seal
        self.reload = reload
        self.versions = versions
        self.running = running
        self.mqtt_running = mqtt_running
        self._one_at_a_time = asyncio.Lock()

    # -- reading -------------------------------------------------------------------------------

    async def current(self) -> dict[str, Any]:
        text = await self._read_file()
        read_only = await asyncio.to_thread(config_access.refusal, self.path)
        return {
            "path": self.path,
            "text": masked(text),
            "base": fingerprint(text),
            "read_only": read_only,
        }

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

    async def check(self, text: str, base: str | None = None) -> Checked:
        """`text` (with `"***N"` for the secrets kept) checked as `check-config` checks a file;
        `base`: the file's `fingerprint` when the text was loaded."""
        current = await self._read_file()
        _same_file(current, base, self.path)
        problems = mask_problems(text, current)
        if problems:
            return Checked(problems)
        return await asyncio.to_thread(self._check, unmasked(text, current))

    async def apply(
        self, text: str, user: str, note: str, base: str | None = None
    ) -> dict[str, Any]:
        async with self._one_at_a_time:
            current = await self._read_file()
            _same_file(current, base, self.path)
            # Said before anything is kept: a file the console can't write is no version.
            read_only = await asyncio.to_thread(config_access.refusal, self.path)
            if read_only is not None:
                raise EditRefused(409, read_only)
            problems = mask_problems(text, current)
            full = unmasked(text, current)
            checked = Checked(problems) if problems else await asyncio.to_thread(self._check, full)
            if not checked.ok:
                raise EditRefused(400, "the configuration does not check out", checked.to_json())
            number = await self._keep(user, full, note, current)
            try:
                await self._write_file(full)
            except EditRefused:
                with contextlib.suppress(StoreError):
                    await self.versions.remove_config_version(number)
                raise
            outcome = await self.reload()
            applied = bool(outcome) and all(line.startswith("applied:") for line in outcome)
            if not applied:
                # The running configuration stayed: the file says so again, and the version
                # goes (only what was applied is kept).
                await self._write_file(current)
                with contextlib.suppress(StoreError):
                    await self.versions.remove_config_version(number)
                raise EditRefused(
                    409, "; ".join(outcome) or "the reload did not answer", checked.to_json()
                )
            return {"version": number, "outcome": outcome, **checked.to_json()}

    async def rollback(self, number: int, user: str) -> dict[str, Any]:
        found = {v.id: v for v in await self._versions()}
        if number not in found:
            raise EditRefused(404, f"version: no version {number} is kept")
        text = await asyncio.to_thread(self.seal.open_all, found[number].text, f"version {number}")
        return await self.apply(text, user, f"rollback to version {number}")

    # -- inside --------------------------------------------------------------------------------

    def _check(self, text: str) -> Checked:
        if len(text.encode()) > MAX_TEXT:
            return Checked([("", f"the text is longer than {MAX_TEXT // 1024} kB")])
        return check_text(text, self.path, self.running(), self.mqtt_running())

    async def _keep(self, user: str, text: str, note: str, current: str) -> int:
        try:
            if not await self.versions.config_versions():
                found = await asyncio.to_thread(self._sealed, current)
                await self.versions.add_config_version("(file)", found, FOUND)
            kept = await asyncio.to_thread(self._sealed, text)
            return await self.versions.add_config_version(user, kept, note)
        except OSError as exc:  # the key file can't be made or read: not kept in clear instead
            raise EditRefused(409, f"not applied: the secrets can't be sealed: {exc}") from None
        except StoreError as exc:
            raise EditRefused(409, f"not applied: the version cannot be kept: {exc}") from None

    def _sealed(self, text: str) -> str:
        """`text` with the value of every key named like a secret sealed (as the store keeps it)."""
        out, last = [], 0
        for secret in _secrets(text):
            out.append(text[last : secret.start])
            out.append(self.seal.seal(secret.value))
            last = secret.end
        out.append(text[last:])
        return "".join(out)

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
            why = await asyncio.to_thread(config_access.write_failed, self.path, exc)
            raise EditRefused(409, why) from None


def fingerprint(text: str) -> str:
    """What a text loaded in the page was edited from: the secrets' numbers refer to it."""
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _same_file(current: str, base: str | None, path: str) -> None:
    if base is not None and base != fingerprint(current):
        raise EditRefused(
            409,
            f"{path} changed since this text was loaded (another edit, or by hand): load it "
            "again and redo the change",
        )


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
        masked(before, numbered=False).splitlines(keepends=True),
        masked(after, numbered=False).splitlines(keepends=True),
        fromfile=f"version {number - 1}" if before else "(nothing)",
        tofile=f"version {number}",
    )
    return "".join(lines)


def _secret(key: str) -> bool:
    return any(word in key.lower() for word in SECRET_WORDS)


@dataclass(frozen=True, slots=True)
class _Found:
    key: str
    start: int
    end: int
    value: str


def _secrets(text: str) -> list[_Found]:
    """Where `text` gives a value to a key named like a secret, in order: a line's own key
    (`password: ...`, `- password_hash: ...`, the value up to a comment) or a key inside a flow
    mapping (`{name: bob, password_hash: ...}`, the value up to `,` or `}`)."""
    found: list[_Found] = []
    offset = 0
    for line in text.splitlines(keepends=True):
        bare = line.rstrip("\r\n")
        block = _BLOCK.match(bare)
        if block is not None and not block["value"].startswith(("{", "[")):
            if _secret(block["key"]) and block["value"] not in ("null", "~", "''", '""'):
                start, end = offset + block.start("value"), offset + block.end("value")
                found.append(_Found(block["key"], start, end, block["value"]))
        else:
            for flow in _FLOW.finditer(bare):
                value = flow["value"].rstrip()
                if _secret(flow["key"]) and value not in ("null", "~", "''", '""'):
                    start = offset + flow.start("value")
                    found.append(_Found(flow["key"], start, start + len(value), value))
        offset += len(line)
    return found


def masked(text: str, numbered: bool = True) -> str:
    """`text` with the value of every key named like a secret shown as `"***N"`: the file's
    N-th secret (`numbered`; a diff shows `"***"`, the same on both sides)."""
    out, last = [], 0
    for number, secret in enumerate(_secrets(text), start=1):
        out.append(text[last : secret.start])
        out.append(f'"{MASK}{number}"' if numbered else f'"{MASK}"')
        last = secret.end
    out.append(text[last:])
    return "".join(out)


def mask_problems(text: str, original: str) -> list[tuple[str, str]]:
    """A secret's value in `text` that is a mask standing for none of `original`'s secrets
    (`"***99"` where the file has 3; `"***"` copied from a diff): (key, reason) each. Kept, it
    would become the password itself."""
    count = len(_secrets(original))
    problems = []
    for secret in _secrets(text):
        if not _MASK_LIKE.fullmatch(secret.value):
            continue
        token = _TOKEN.fullmatch(secret.value)
        if token is not None and 1 <= int(token["number"]) <= count:
            continue
        held = f"{MASK}1 to {MASK}{count}" if count else "none"
        problems.append(
            (
                secret.key,
                f"{secret.value} stands for no secret of the file (it has {held}): type the "
                "value itself, or load the file again to get its masks",
            )
        )
    return problems


def unmasked(text: str, original: str) -> str:
    """`text` with each `"***N"` replaced by the N-th secret of `original`, as the file has it
    (wherever the line went: a user removed above another keeps the other's hash). A number
    `original` doesn't have is left as it is (`mask_problems` refuses it at its key)."""
    secrets = [secret.value for secret in _secrets(original)]

    def secret(match: re.Match[str]) -> str:
        number = int(match["number"])
        return secrets[number - 1] if 1 <= number <= len(secrets) else match[0]

    return _TOKEN.sub(secret, text)
